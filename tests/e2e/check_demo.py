#!/usr/bin/python3
"""Checks a run of the whole-body demo (scripts/demo.sh --out DIR): contacts at the right places.

  check_demo.py OUT_DIR SCENE_DIR BUILD_DIR

Every contact skinbus-listen received (OUT_DIR/contacts.jsonl) must come from a patch the scene
pressed, on that patch's link; contacts at least 1 mm deep must lie, in the base frame, within the
model's error (median < 5 mm, p90 < 12 mm per patch) of where the press is on the moving body:
skinbus-locate at the contact's time into the arm trajectory (time zero from OUT_DIR/joints.log).
A patch pressed twice at once is judged against the nearer press, a sliding press against the
nearest point of its path. Every scripted press must have been seen. The two fingers on one
patch must be published as two contacts at once, each on its press with a track of its own; the
sliding press's shear must point along the slide in the base frame, its size the scene's
friction times the normal force. PASS/FAIL lines; exit 1 on any FAIL.
"""
import json
import math
import re
import subprocess
import sys
from xml.etree import ElementTree


def read_presses(scene):
    """The scene's scripted presses: node -> [press], each a dict with u, v, the slide's end (the
    same for a press that stays) and its friction."""
    presses = {}
    for line in open(f"{scene}/presses.csv"):
        if line.startswith("#") or not line.strip():
            continue
        f = [float(x) for x in line.strip().split(",")]
        p = {"t0": f[0], "t1": f[1], "u": f[2], "v": f[3], "u_end": f[2], "v_end": f[3],
             "friction": 0.0}
        if len(f) >= 9:
            p["u_end"], p["v_end"] = f[7], f[8]
            p["friction"] = f[9] if len(f) >= 10 else 0.0
        presses.setdefault(int(f[6]), []).append(p)
    return presses


def nearest_on(press, u, v):
    """The point of the press's path (a point, or a slide's segment) nearest (u, v), and its
    distance."""
    au, av, bu, bv = press["u"], press["v"], press["u_end"], press["v_end"]
    du, dv = bu - au, bv - av
    n2 = du * du + dv * dv
    t = 0.0 if n2 == 0 else max(0.0, min(1.0, ((u - au) * du + (v - av) * dv) / n2))
    pu, pv = au + t * du, av + t * dv
    return pu, pv, math.hypot(u - pu, v - pv)


def nearest_press(presses, node, u, v):
    """(index, point u, point v, distance) of the node's press nearest (u, v)."""
    best = None
    for i, p in enumerate(presses[node]):
        pu, pv, d = nearest_on(p, u, v)
        if best is None or d < best[3]:
            best = (i, pu, pv, d)
    return best


def sliding_presses(presses):
    """(node, press) for every press that drags the skin (a slide with friction)."""
    return [(node, p) for node, ps in sorted(presses.items()) for p in ps if p["friction"] > 0]


def slide_direction(build, skin, node, press):
    """The unit direction of a sliding press in the base frame (a patch that does not move)."""
    ends = "".join(f"0 {node} {u} {v}\n" for u, v in ((press["u"], press["v"]),
                                                     (press["u_end"], press["v_end"])))
    a, b = [list(map(float, t.split()[2:5])) for t in subprocess.run(
        [f"{build}/tools/skinbus-locate", "--map", skin, "-"], input=ends, text=True,
        capture_output=True, check=True).stdout.splitlines()]
    along = [y - x for x, y in zip(a, b)]
    n = math.hypot(*along)
    return [x / n for x in along]


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    out, scene, build = sys.argv[1:]
    presses = read_presses(scene)
    m = re.search(r"time zero (\d+) us", open(f"{out}/joints.log").read())
    if not m:
        sys.exit("check_demo.py: no time zero in joints.log")
    t_zero_us = int(m.group(1))
    contacts, frames, publications = [], set(), []
    for line in open(f"{out}/contacts.jsonl"):
        j = json.loads(line)
        if j["type"] == "contacts":
            frames.add(j["base_frame"])
            contacts += j["contacts"]
            publications.append(j["contacts"])
            for c in j["contacts"]:
                c["stamp_us"] = j["stamp_us"]
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    check("contacts received over DDS", len(contacts) > 100, f"{len(contacts)} contacts")
    # frame_id: the robot's root link (the link no joint has as its child), a frame of its TF tree.
    robot = re.search(r'^robot: "?([^"\n]+)"?', open(f"{out}/skin.yaml").read(), re.M).group(1)
    urdf = ElementTree.parse(robot).getroot()
    children = {j.find("child").get("link") for j in urdf.iter("joint")}
    roots = [l.get("name") for l in urdf.iter("link") if l.get("name") not in children]
    check("contacts in the robot's root link frame", frames == set(roots),
          f"frame_id {sorted(frames)}, URDF root {roots}")
    stray = sorted({c["node"] for c in contacts if c["node"] not in presses})
    check("contacts only on pressed patches", not stray, f"stray nodes {stray}" if stray else "")
    deep = [c for c in contacts if c["node"] in presses and c["depth_mm"] >= 1.0]
    for c in deep:
        c["press"], c["truth_u"], c["truth_v"], _ = nearest_press(presses, c["node"], c["u_mm"],
                                                                  c["v_mm"])
    query = "".join(f"{(c['stamp_us'] - t_zero_us) / 1e6:.4f} {c['node']} "
                    f"{c['truth_u']} {c['truth_v']}\n" for c in deep)
    truth = subprocess.run([f"{build}/tools/skinbus-locate", "--map", f"{out}/skin.yaml",
                            "--joints", f"{scene}/arms.csv", "-"], input=query, text=True,
                           capture_output=True, check=True).stdout.splitlines()
    errs, wrong_link = {}, []
    for c, t in zip(deep, truth):
        node, link, x, y, z, *_ = t.split()
        if c["link"] != link:
            wrong_link.append(c["node"])
        errs.setdefault(c["node"], []).append(
            math.dist(c["position_mm"], (float(x), float(y), float(z))))
    check("contacts on their patch's link", not wrong_link,
          f"wrong on nodes {sorted(set(wrong_link))}" if wrong_link else "")
    scripted = {(n, i) for n, ps in presses.items() for i in range(len(ps))}
    seen = {(c["node"], c["press"]) for c in deep}
    missing = sorted(scripted - seen)
    check("every scripted press seen at least 1 mm deep", not missing,
          f"{len(scripted) - len(missing)} of {len(scripted)}" + (f", missing {missing}" if missing else ""))

    # Two fingers on one patch: two contacts in one publication, each near its own press, each
    # press followed by one track.
    for node, ps in sorted(presses.items()):
        if len(ps) < 2:
            continue
        both, tracks = 0, {0: {}, 1: {}}
        for published in publications:
            mine = [c for c in published if c["node"] == node and c["depth_mm"] >= 1.0]
            near = [nearest_press(presses, node, c["u_mm"], c["v_mm"]) for c in mine]
            if len(mine) == 2 and {n[0] for n in near} == {0, 1} and max(n[3] for n in near) < 5:
                both += 1
                for c, n in zip(mine, near):
                    tracks[n[0]][c["track_id"]] = tracks[n[0]].get(c["track_id"], 0) + 1
        overlap_s = min(ps[0]["t1"], ps[1]["t1"]) - max(ps[0]["t0"], ps[1]["t0"])
        check(f"node {node}: two fingers published as two contacts at once", both >= 15,
              f"{both} publications with both (the presses overlap {overlap_s:.1f} s)")
        kept = [max(t.values()) / sum(t.values()) if t else 0 for t in tracks.values()]
        shared = set(tracks[0]) & set(tracks[1])
        check(f"node {node}: each finger keeps a track of its own", min(kept) >= 0.8 and not shared,
              f"dominant track share {kept[0]:.2f}, {kept[1]:.2f}; shared IDs {sorted(shared)}")

    # A sliding press's shear: along the slide in the base frame, friction times normal force.
    for node, p in sliding_presses(presses):
        along = slide_direction(build, f"{out}/skin.yaml", node, p)
        sheared = [c for c in contacts if c["node"] == node and "shear" in c["flags"] and
                   math.hypot(*c["shear_n"]) > 3 * c["shear_uncertainty_n"] and c["depth_mm"] >= 1]
        cosines = sorted(sum(x * y for x, y in zip(c["shear_n"], along)) / math.hypot(*c["shear_n"])
                         for c in sheared)
        ratios = sorted(math.hypot(*c["shear_n"]) / c["force_n"] for c in sheared)
        check(f"node {node}: the sliding press's shear is seen", len(sheared) >= 20,
              f"{len(sheared)} contacts with a shear beyond 3 sigma")
        if sheared:
            med_cos, med_ratio = cosines[len(cosines) // 2], ratios[len(ratios) // 2]
            check(f"node {node}: shear along the slide", med_cos > 0.9,
                  f"median cosine to the slide {med_cos:.3f}")
            check(f"node {node}: shear / normal force is the friction {p['friction']}",
                  abs(med_ratio - p["friction"]) < 0.15, f"median {med_ratio:.3f}")
        # Along the slide (patch frame), from its start to its end within 10 mm.
        du, dv = p["u_end"] - p["u"], p["v_end"] - p["v"]
        length = math.hypot(du, dv)
        s = [((c["u_mm"] - p["u"]) * du + (c["v_mm"] - p["v"]) * dv) / length
             for c in contacts if c["node"] == node and c["depth_mm"] >= 1]
        check(f"node {node}: the contact follows the slide",
              bool(s) and min(s) < 10 and max(s) > length - 10,
              f"from {min(s):.1f} to {max(s):.1f} mm of {length:.1f}" if s else "no contact")
    for node, e in sorted(errs.items()):
        e.sort()
        med, p90 = e[len(e) // 2], e[int(0.9 * len(e))]
        check(f"node {node}: on the moving body within the model's error", med < 5 and p90 < 12,
              f"{len(e)} contacts, median {med:.2f} mm, p90 {p90:.2f} mm")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
