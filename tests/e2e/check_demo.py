#!/usr/bin/python3
"""Checks a run of the whole-body demo (scripts/demo.sh --out DIR): contacts at the right places.

  check_demo.py OUT_DIR SCENE_DIR BUILD_DIR

Every contact skinbus-listen received (OUT_DIR/contacts.jsonl) must come from a patch the scene
pressed, on that patch's link; contacts at least 1 mm deep must lie, in the base frame, within the
model's error (median < 5 mm, p90 < 12 mm per patch) of where the press is on the moving body:
skinbus-locate at the contact's time into the arm trajectory (time zero from OUT_DIR/joints.log).
Every scripted press must have been seen. PASS/FAIL lines; exit 1 on any FAIL.
"""
import json
import math
import re
import subprocess
import sys
from xml.etree import ElementTree


def read_presses(scene):
    """The scene's scripted presses: node -> (u_mm, v_mm) (one press a patch)."""
    presses = {}
    for line in open(f"{scene}/presses.csv"):
        if line.startswith("#") or not line.strip():
            continue
        t0, t1, u, v, depth, tip, node = line.strip().split(",")
        presses[int(node)] = (float(u), float(v))
    return presses


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    out, scene, build = sys.argv[1:]
    presses = read_presses(scene)
    m = re.search(r"time zero (\d+) us", open(f"{out}/joints.log").read())
    if not m:
        sys.exit("check_demo.py: no time zero in joints.log")
    t_zero_us = int(m.group(1))
    contacts, frames = [], set()
    for line in open(f"{out}/contacts.jsonl"):
        j = json.loads(line)
        if j["type"] == "contacts":
            frames.add(j["base_frame"])
            contacts += j["contacts"]
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
    query = "".join(f"{(c['stamp_us'] - t_zero_us) / 1e6:.4f} {c['node']} "
                    f"{presses[c['node']][0]} {presses[c['node']][1]}\n" for c in deep)
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
    missing = sorted(set(presses) - set(errs))
    check("every scripted press seen at least 1 mm deep", not missing,
          f"{len(presses) - len(missing)} of {len(presses)}" + (f", missing {missing}" if missing else ""))
    for node, e in sorted(errs.items()):
        e.sort()
        med, p90 = e[len(e) // 2], e[int(0.9 * len(e))]
        check(f"node {node}: on the moving body within the model's error", med < 5 and p90 < 12,
              f"{len(e)} contacts, median {med:.2f} mm, p90 {p90:.2f} mm")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
