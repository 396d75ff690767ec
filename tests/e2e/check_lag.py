#!/usr/bin/python3
"""Checks a starved host: every contact where the press was, the lag bounded and reported.

  check_lag.py CONTACTS --host-log HOST_ERR --locate BIN --map MAP --presses CSV
      --trajectory CSV --start US --max-lag-ms MS [--tolerance MM] [--max-error MM]

CONTACTS: JSON lines of skinbus-listen --status (what the host published on DDS). HOST_ERR: the
host's stderr with --stats (its log). The arms move along --trajectory from --start (the joint
publisher's time zero, CLOCK_REALTIME us); the presses are skinbus-patchd --contacts lines.

  - Every contact of a pressed patch at least 1 mm deep that carries neither stale_kinematics
    nor no_kinematics lies within --max-error of where skinbus-locate puts its press at
    trajectory time (array stamp - start), and their median error is below --tolerance. A
    flagged contact (the joint states did not cover its time) is allowed off, and counted: at
    most 5 % of them.
  - No contact from a patch that was not pressed, and every press seen.
  - The control: where the press had moved to by the time the host published (its stamp plus
    the host's median latency) is, in the median, more than 2 x --max-error away from where it
    was: a host placing late samples with the newest pose would fail the check above.
  - The lag: the host superseded late samples (its --stats line counts them), said so on its log
    (host_lagging) and on the status topic (a host_lagging event), and its p99 latency from frame
    arrival to publication is below twice --max-lag-ms.
Prints PASS/FAIL lines; exit 1 on any FAIL.
"""
import argparse
import json
import math
import re
import subprocess
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("contacts")
    ap.add_argument("--host-log", required=True)
    ap.add_argument("--locate", required=True)
    ap.add_argument("--map", required=True)
    ap.add_argument("--presses", required=True)
    ap.add_argument("--trajectory", required=True)
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--max-lag-ms", type=float, required=True)
    ap.add_argument("--tolerance", type=float, default=3.0, help="median error, mm")
    ap.add_argument("--max-error", type=float, default=8.0, help="largest error, mm")
    a = ap.parse_args()

    presses = {}
    for line in open(a.presses):
        if line.startswith("#") or not line.strip():
            continue
        _, _, u, v, _, _, node = line.strip().split(",")
        presses[int(node)] = (float(u), float(v))
    contacts, events = [], []
    for line in open(a.contacts):
        if not line.startswith("{"):
            continue
        j = json.loads(line)
        if j["type"] == "contacts":
            for c in j["contacts"]:
                c["stamp_us"] = j["stamp_us"]
                contacts.append(c)
        elif j["type"] == "patch_status":
            events += j["events"]
    log = open(a.host_log).read()
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    def locate(query):
        out = subprocess.run([a.locate, "--map", a.map, "--joints", a.trajectory, "-"],
                             input="".join(f"{t:.6f} {n} {u} {v}\n" for t, n, u, v in query),
                             text=True, capture_output=True, check=True).stdout.splitlines()
        return [(line.split()[1], tuple(float(x) for x in line.split()[2:5])) for line in out]

    check("contacts received over DDS", len(contacts) > 50, f"{len(contacts)} contacts")
    stray = sorted({c["node"] for c in contacts if c["node"] not in presses})
    check("contacts only on pressed patches", not stray, f"stray nodes {stray}" if stray else "")
    deep = [c for c in contacts if c["node"] in presses and c["depth_mm"] >= 1.0]
    flagged = [c for c in deep if {"stale_kinematics", "no_kinematics"} & set(c["flags"])]
    placed = [c for c in deep if c not in flagged]
    check("few contacts flagged for their kinematics", len(flagged) <= 0.05 * max(len(deep), 1),
          f"{len(flagged)} of {len(deep)}")
    m = re.search(r"latency frame arrival -> publication over \d+ samples: p50 (\d+) us, "
                  r"p99 (\d+) us", log)
    check("the host measured its latency", m is not None)
    p50_us, p99_us = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
    query = [((c["stamp_us"] - a.start) / 1e6, c["node"], *presses[c["node"]]) for c in placed]
    truth = locate(query)
    later = locate([(t + p50_us / 1e6, n, u, v) for t, n, u, v in query])
    errs, moved, wrong_link = {}, [], []
    for c, (link, p), (_, q) in zip(placed, truth, later):
        if c["link"] != link:
            wrong_link.append(c["node"])
        errs.setdefault(c["node"], []).append(math.dist(c["position_mm"], p))
        moved.append(math.dist(p, q))
    check("contacts on their patch's link", not wrong_link,
          f"wrong on nodes {sorted(set(wrong_link))}" if wrong_link else "")
    missing = sorted(set(presses) - set(errs))
    check("every press seen", not missing, f"missing {missing}" if missing else "")
    for node, e in sorted(errs.items()):
        e.sort()
        check(f"node {node}: every contact where its press was",
              e[len(e) // 2] < a.tolerance and e[-1] < a.max_error,
              f"{len(e)} contacts, median {e[len(e) // 2]:.2f} mm, max {e[-1]:.2f} mm")
    moved.sort()
    med_moved = moved[len(moved) // 2] if moved else 0
    check("control: the presses moved far while the host was busy", med_moved > 2 * a.max_error,
          f"median {med_moved:.1f} mm in the host's median latency of {p50_us / 1e3:.0f} ms")
    s = re.search(r", late (\d+)\)", log)
    late = int(s.group(1)) if s else 0
    check("the host superseded late samples", late > 0, f"{late} late")
    check("its log says so", "host_lagging:" in log)
    check("the status topic says so", any(e["event"] == "host_lagging" for e in events),
          f"events {sorted({e['event'] for e in events})}")
    check("the lag stayed bounded", 0 < p99_us < 2 * a.max_lag_ms * 1000,
          f"p50 {p50_us / 1e3:.0f} ms, p99 {p99_us / 1e3:.0f} ms (bound {a.max_lag_ms:.0f} ms)")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
