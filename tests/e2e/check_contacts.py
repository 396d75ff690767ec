#!/usr/bin/python3
"""Checks contacts (JSON lines of skinbus-host --json or skinbus-listen) against the truth.

  check_contacts.py TRUTH CONTACTS [--reference HOST_JSONL] [--min-arrays N] [--min-per-node N]

TRUTH: `skinbus-locate` output for every pressed point (node link x y z nx ny nz), one press
per node. Passes when every contact is on a pressed patch and its link, tracked, placed with
kinematics, and per pressed node the contacts at least 1 mm deep lie within the model's error
(median < 4 mm, p90 < 8 mm) of the truth. With --reference, the contact arrays received must be
at least 90 % of those the host published. Prints PASS/FAIL lines; exit 1 on any FAIL.
"""
import argparse
import json
import math
import sys


def contact_arrays(path):
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line.startswith("{"):
                j = json.loads(line)
                if j.get("type") == "contacts":
                    out.append(j)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("truth")
    ap.add_argument("contacts")
    ap.add_argument("--reference")
    ap.add_argument("--min-arrays", type=int, default=20)
    ap.add_argument("--flags-allowed", default="",
                    help="comma-separated flags a contact may carry (no_kinematics is refused "
                         "unless listed: a robot without joint states is a setup error)")
    ap.add_argument("--min-per-node", type=int, default=10,
                    help="contacts at least 1 mm deep needed per pressed node")
    a = ap.parse_args()
    truth = {}
    with open(a.truth) as f:
        for line in f:
            node, link, x, y, z, *_ = line.split()
            truth[int(node)] = (link, (float(x), float(y), float(z)))
    got = contact_arrays(a.contacts)
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    check("contacts published", len(got) >= a.min_arrays, f"{len(got)} arrays")
    if a.reference:
        ref = contact_arrays(a.reference)
        check("the subscriber received what the host published", len(got) >= 0.9 * len(ref),
              f"{len(got)} of {len(ref)}")
    errs = {n: [] for n in truth}
    wrong = []
    allowed = set(filter(None, a.flags_allowed.split(",")))
    for arr in got:
        for c in arr["contacts"]:
            n = c["node"]
            if n not in truth or c["link"] != truth[n][0] or c["track_id"] == 0 \
                    or ("no_kinematics" in c["flags"] and "no_kinematics" not in allowed):
                wrong.append(n)
                continue
            if c["depth_mm"] >= 1.0:
                errs[n].append(math.dist(c["position_mm"], truth[n][1]))
    check("contacts only on pressed patches, on the right links, tracked, with kinematics",
          not wrong, f"bad nodes {sorted(set(wrong))}" if wrong else "")
    for n, e in sorted(errs.items()):
        e.sort()
        med = e[len(e) // 2] if e else float("nan")
        p90 = e[int(0.9 * len(e))] if e else float("nan")
        check(f"node {n}: body-frame position within the model's error",
              len(e) >= a.min_per_node and med < 4.0 and p90 < 8.0,
              f"{len(e)} contacts >= 1 mm deep, median {med:.2f} mm, p90 {p90:.2f} mm")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
