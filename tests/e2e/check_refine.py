#!/usr/bin/env python3
"""Checks skinbus-host's physics refinement against the presses of a simulated patch.

  check_refine.py PRESSES.csv REFINED.jsonl NETWORK.jsonl OVERBUDGET.jsonl

Contacts are matched to the press held at their time (without the first and last 0.25 s of the
press: the ramps), by their patch-local (u, v). Refined: no held contact flagged unrefined, each with
an uncertainty below 0.6 mm (the fit's, not the network's table), mean (u, v) error below 0.6x
the network's and below 0.5 mm (the ramps and the creeping release are not judged). Over the budget: every contact flagged unrefined, at the network's
places.
"""
import json
import math
import sys


def presses(path):
    out = []
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        t0, t1, u, v, d, _, node = line.split(",")
        out.append((float(t0), float(t1), float(u), float(v), float(d), int(node)))
    return out


def contacts(path):
    """(seconds from the log's first publication, contact) for every contact published."""
    out, first = [], None
    for line in open(path):
        m = json.loads(line)
        if m.get("type") != "contacts":
            continue
        if first is None:
            first = m["stamp_us"]
        for c in m["contacts"]:
            out.append((m["stamp_us"], c))
    return out


def held(ps, cs, log_start_us):
    """The contacts of the held part of a press, each with its (u, v) error."""
    out = []
    for stamp, c in cs:
        t = (stamp - log_start_us) * 1e-6
        for t0, t1, u, v, _, node in ps:
            if node == c["node"] and t0 + 0.25 <= t <= t1 - 0.25:
                out.append((math.hypot(c["u_mm"] - u, c["v_mm"] - v), c))
    return out


def main():
    ps = presses(sys.argv[1])
    runs = {name: contacts(path) for name, path in zip(("refined", "network", "over"), sys.argv[2:5])}
    bad = []
    for name, cs in runs.items():
        if not cs:
            bad.append(f"{name}: no contacts")
    if bad:
        print("\n".join("FAIL " + b for b in bad))
        return 1
    # The log's time zero: the patch daemon starts with the log; the first press begins at t0.
    # Publications carry sample times; align on the first contact of each run (the first press's
    # first sample, within a sample period of t0).
    result = {}
    for name, cs in runs.items():
        start = cs[0][0] - int(ps[0][0] * 1e6)
        result[name] = held(ps, cs, start)
    ref = [e for e, _ in result["refined"]]
    net = [e for e, _ in result["network"]]
    mean = lambda xs: sum(xs) / len(xs) if xs else float("nan")
    print(f"check_refine: held samples {len(ref)} refined, {len(net)} network; mean (u, v) error "
          f"refined {mean(ref):.3f} mm, network {mean(net):.3f} mm")
    if len(ref) < 50 or len(net) < 50:
        bad.append("too few held samples to compare")
    if not mean(ref) < 0.6 * mean(net):
        bad.append(f"refined {mean(ref):.3f} mm is not well below the network's {mean(net):.3f} mm")
    if not mean(ref) < 0.5:
        bad.append(f"refined mean error {mean(ref):.3f} mm")
    unrefined = sum(1 for _, c in result["refined"] if "unrefined" in c["flags"])
    if unrefined:
        bad.append(f"{unrefined} held contacts of the refined run are flagged unrefined")
    sig = [c["uncertainty_mm"] for _, c in result["refined"]]
    print(f"check_refine: stated uncertainty of the held contacts {min(sig):.3f}-{max(sig):.3f} mm")
    if max(sig) > 0.6:
        bad.append(f"a held refined contact states {max(sig):.3f} mm")
    over = runs["over"]
    if not all("unrefined" in c["flags"] for _, c in over):
        bad.append("over the budget, a contact is not flagged unrefined")
    # Compared on the samples both runs published: a replay on a loaded machine may supersede a
    # sample in one run and not in the other (the host skips what it cannot place in time).
    def places(cs):
        out = {}
        for s, c in cs:
            out.setdefault(s, set()).add((c["node"], round(c["u_mm"], 9), round(c["v_mm"], 9)))
        return out
    net_places, over_places = places(runs["network"]), places(over)
    common = net_places.keys() & over_places.keys()
    print(f"check_refine: {len(common)} samples published by both the network and the over-budget "
          f"run (of {len(net_places)} and {len(over_places)})")
    if len(common) < 0.9 * max(len(net_places), len(over_places)):
        bad.append("the network and over-budget runs published too few of the same samples")
    if any(net_places[s] != over_places[s] for s in common):
        bad.append("over the budget, the contacts are not the network's")
    for b in bad:
        print("FAIL " + b)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
