#!/usr/bin/python3
"""Checks that an identified unit's simulated fields match the unit it was identified from.

  check_unit_fields.py UNIT.csv IDENTIFIED.csv NOMINAL.csv [--max-ratio R]

Three datasets of the same presses and the same noise seed (skinbus-dataset --plan random-test,
one --uid): from the real unit (--fabricated), from its unit file (--unit) and from the nominal
model. Over the samples at least 1 mm deep, the RMS field difference identified - unit must be
below R (default 0.3) times nominal - unit. Prints both; exit 1 when not.
"""
import argparse
import csv
import math
import sys


def load(path):
    with open(path) as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    head = rows[0]
    channels = [k for k, name in enumerate(head) if name.endswith("_ut")]
    depth = head.index("depth_mm")
    return [(float(r[depth]), [float(r[k]) for k in channels]) for r in rows[1:]]


def rms_difference(a, b):
    if len(a) != len(b):
        sys.exit(f"FAIL the datasets differ in length ({len(a)} and {len(b)} rows)")
    total, n = 0.0, 0
    for (depth_a, fa), (depth_b, fb) in zip(a, b):
        if abs(depth_a - depth_b) > 1e-9:
            sys.exit("FAIL the datasets are not of the same presses")
        if depth_a < 1.0:
            continue
        total += sum((x - y) ** 2 for x, y in zip(fa, fb))
        n += len(fa)
    if n == 0:
        sys.exit("FAIL no sample at least 1 mm deep")
    return math.sqrt(total / n)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("unit")
    p.add_argument("identified")
    p.add_argument("nominal")
    p.add_argument("--max-ratio", type=float, default=0.3)
    a = p.parse_args()
    unit = load(a.unit)
    identified = rms_difference(load(a.identified), unit)
    nominal = rms_difference(load(a.nominal), unit)
    verdict = "PASS" if identified < a.max_ratio * nominal else "FAIL"
    print(f"{verdict} field RMS vs the unit: identified {identified:.3f} uT, nominal "
          f"{nominal:.3f} uT (ratio {identified / nominal:.3f}, limit {a.max_ratio})")
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
