#!/usr/bin/python3
"""Drives the web view of a running demo in headless Chromium and checks what the page shows.

  check_view.py URL DEMO_OUT SCENE_DIR BUILD_DIR ARTEFACT_DIR SECONDS READY_FILE

Once the page is up it creates READY_FILE (the demo runs with --start-when READY_FILE: its host
and touches start then, so the page sees the scene from the first press on any machine load) and
reads the page back until SECONDS after the scene's time zero (DEMO_OUT/joints.log): its summary
(window.skinbusView.summary(), its own scene objects, not the server's JSON) every 0.1 s, and the
contacts its scene held after each contacts message (window.skinbusView.record()), so that no
instant is missed however seldom a loaded machine reads the page.

It must: load the robot from its URDF and draw the skin map's 12 patches on their links, where
the project's forward kinematics puts them at the joint values the page applied (urdf-loader's
kinematics against skinbus-locate, within 1 mm); show contacts, which must sit where the scripted
presses are on the moving body (skinbus-locate at the contact's time, as check_demo.py: at least
1 mm deep, median < 5 mm, p90 < 12 mm per patch); show node 9's two fingers at once (as
check_demo.py: at least 15 instants) and node 10's sliding press's shear as an arrow along it;
show the sensors' field change of the pressed patches (read from the bus) and draw a selected
pressed patch's heat map; show node 11 stale or offline once its daemon is stopped; raise its
stalled banner once the host is gone; log no page errors. Meanwhile hostile clients (malformed
requests, oversized and binary frames, 40 connections at once) must not disturb it. Writes
ARTEFACT_DIR/view.png (a press, its patch selected with its sensor panel) and
ARTEFACT_DIR/contacts.json (the contacts read back, with their truth and error). PASS/FAIL lines;
exit 1 on any FAIL.
"""
import json
import math
import os
import re
import socket
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cdp  # noqa: E402
from check_demo import nearest_press, read_presses, slide_direction, sliding_presses  # noqa: E402


def hostile_clients(port):
    """Bounded abuse of the server on the loopback: every socket closed, a few seconds at most."""
    key = "dGhlIHNhbXBsZSBub25jZQ=="
    upgrade = (f"GET /ws HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n\r\n").encode()
    payloads = [
        b"\x00\x01garbage\r\n\r\n",
        b"GET /../../etc/passwd HTTP/1.1\r\n\r\n",
        b"GET / HTTP/1.1\r\n" + b"X: " + b"a" * 20000 + b"\r\n\r\n",
        upgrade + b"\x81\x7f\x7f\xff\xff\xff\xff\xff\xff\xff",   # a 2^63-byte frame
        upgrade + b"\x82\x82abcd\x00\x00",                      # a binary frame
        upgrade + b"\x81\x02hi",                                # unmasked
        upgrade + b"\x81\xfe\x20\x00abcd" + b"x" * 8192,        # 8 KiB text frame
    ]
    socks = []
    for i in range(40):
        s = socket.create_connection(("127.0.0.1", port), timeout=2)
        try:
            s.sendall(payloads[i % len(payloads)])
        except OSError:
            pass
        socks.append(s)
    time.sleep(0.5)
    for s in socks:
        s.close()


def locate(build, skin, joints_csv, lines):
    out = subprocess.run([f"{build}/tools/skinbus-locate", "--map", skin, "--joints", joints_csv, "-"],
                         input="".join(lines), text=True, capture_output=True, check=True).stdout
    return [l.split() for l in out.splitlines()]


def scene_zero_us(demo):
    """The scene's time zero (CLOCK_REALTIME, us) from skinbus-joints' log; None before it starts."""
    try:
        m = re.search(r"time zero (\d+) us", open(f"{demo}/joints.log").read())
    except FileNotFoundError:
        return None
    return int(m.group(1)) if m else None


def main():
    if len(sys.argv) != 8:
        sys.exit(__doc__)
    url, demo, scene, build, artefacts, seconds, ready_file = sys.argv[1:]
    seconds = float(seconds)
    port = int(re.search(r":(\d+)", url).group(1))
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    presses = read_presses(scene)

    contacts = {}  # (track, stamp) -> page contact
    fields_max = {}  # node -> the largest field change the page got (uT)
    panel = None     # (node, the selected patch's heat map maximum)
    states = {}    # node -> states seen
    stalled_seen = False
    centre_checks = []
    shot = False
    with cdp.Browser() as browser:
        browser.open(url)
        try:
            browser.wait_for("window.skinbusView && window.skinbusView.summary().robot_loaded", 30)
        except Exception as e:  # noqa: BLE001
            check("the page loads the robot", False, str(e))
            return 1
        s = browser.evaluate("window.skinbusView.summary()")
        check("the page loads the robot from its URDF", s["robot_loaded"] and s["links"] > 10,
              f"{s['links']} links")
        drawn = sorted(p["node"] for p in s["patches"] if p["drawn"])
        check("the skin map's 12 patches are drawn", drawn == list(range(1, 13)), f"drawn {drawn}")
        # The page keeps what its scene holds after every contacts message (read at each poll):
        # every instant counts, however seldom this loaded machine gets to read the page.
        browser.evaluate("window.skinbusView.record(20000)")
        snapshots, dropped = [], 0
        open(ready_file, "w").close()  # the demo's host and touches start now
        page_up_us = int(time.time() * 1e6)  # CLOCK_REALTIME, as the scene's time zero
        deadline = time.monotonic() + seconds + 180  # the host's start and the scene's, bounded
        t_zero_us = None
        hostile_done = False
        reads = 0  # summaries read while the scene ran
        errors = None  # the page's errors while the host and the server still run
        while time.monotonic() < deadline:
            if t_zero_us is None:
                t_zero_us = scene_zero_us(demo)
            # Seconds of the scene (negative before it starts).
            scene_s = -1.0 if t_zero_us is None else time.time() - t_zero_us / 1e6
            if scene_s >= seconds:
                break
            # One evaluation a poll: the summary and what the page recorded since the last.
            s, recorded = browser.evaluate(
                "[window.skinbusView.summary(), window.skinbusView.takeRecorded()]")
            reads += scene_s >= 0
            snapshots += recorded["snapshots"]
            dropped += recorded["dropped"]
            # (The summary's contacts are the last snapshot's.)
            for c in (c for shot in recorded["snapshots"] for c in shot):
                contacts[(c["track_id"], c["stamp_us"])] = c
            for p in s["patches"]:
                states.setdefault(p["node"], set()).add(p["state"])
            for node, m in s["fields"].items():
                fields_max[int(node)] = max(fields_max.get(int(node), 0), m)
            # A patch with a contact shown whose latest fields show its press (a contact can
            # outlive its press on the page when the host runs late): selected as a click would,
            # until its panel has drawn one.
            pressed = [c["node"] for c in s["contacts"] if s["fields"].get(str(c["node"]), 0) >= 5]
            if not shot and pressed and scene_s > 5:
                node = pressed[0]
                panel = (node, browser.evaluate(f"window.skinbusView.selectPatch({node})"))
                if panel[1] is not None and panel[1] >= 5:  # the picture: a press and its sensors
                    time.sleep(0.3)
                    browser.screenshot(f"{artefacts}/view.png")
                    shot = True
            stalled_seen |= bool(s["stalled"]) and scene_s > seconds - 6
            if s["joints"] and len(centre_checks) < 5 and scene_s > 3:
                centre_checks.append(s)
            if errors is None and scene_s > seconds - 8:
                errors = s["errors"] + browser.console_errors()
            if not hostile_done and scene_s > 4:
                hostile_clients(port)
                hostile_done = True
            time.sleep(0.1)  # the page keeps every contacts message in between
        if not shot:
            browser.screenshot(f"{artefacts}/view.png")
        final = browser.evaluate("window.skinbusView.summary()")
        check("no page errors while the host ran", not errors, "; ".join(errors or [])[:500])
        print(f"  page messages: {final['messages']}, {final['fps']:.0f} frames/s at the end")

    # urdf-loader's forward kinematics against the project's, at the joint values the page applied.
    worst = 0.0
    for s in centre_checks:
        names = sorted(s["joints"])
        with open("joints_now.csv", "w") as f:
            f.write("time_s," + ",".join(names) + "\n0," + ",".join(str(s["joints"][n]) for n in names) + "\n")
        truth = locate(build, f"{demo}/skin.yaml", "joints_now.csv",
                       [f"0 {p['node']} 0 0\n" for p in s["patches"]])
        for p, t in zip(s["patches"], truth):
            worst = max(worst, math.dist(p["centre_base_mm"], [float(x) for x in t[2:5]]))
    check("patches where the project's kinematics puts them (urdf-loader in the page)",
          centre_checks and worst < 1.0, f"{len(centre_checks)} poses, worst {worst:.3f} mm")

    # Contacts read back from the page against the presses on the moving body.
    if t_zero_us is None:
        check("the scene started", False, f"no time zero in {demo}/joints.log")
        return 1
    print(f"  the page was up {(t_zero_us - page_up_us) / 1e6:.1f} s before the scene's time zero")
    shown = [c for c in contacts.values() if c["node"] in presses]
    check("contacts shown by the page", len(shown) > 50 and dropped == 0,
          f"{len(shown)} distinct contacts read back from {len(snapshots)} contact messages "
          f"({dropped} dropped) in {reads} reads of the page")
    # As check_demo.py: the contacts at least 1 mm deep (a press's first and last samples are
    # shallow, where no estimator places them well).
    deep = [c for c in shown if c["depth_mm"] >= 1.0]
    # Each against its press (the nearer of two, the nearest point of a slide), as check_demo.py.
    for c in deep:
        _, c["truth_u"], c["truth_v"], _ = nearest_press(presses, c["node"], c["u_mm"], c["v_mm"])
    truth = locate(build, f"{demo}/skin.yaml", f"{scene}/arms.csv",
                   [f"{(c['stamp_us'] - t_zero_us) / 1e6:.4f} {c['node']} "
                    f"{c['truth_u']} {c['truth_v']}\n" for c in deep])
    errs = {}
    for c, t in zip(deep, truth):
        c["truth_mm"] = [float(x) for x in t[2:5]]
        c["error_mm"] = math.dist(c["position_base_mm"], c["truth_mm"])
        errs.setdefault(c["node"], []).append(c["error_mm"])
    with open(f"{artefacts}/contacts.json", "w") as f:
        json.dump(sorted(deep, key=lambda c: c["stamp_us"]), f, indent=0)
    bad, medians = [], []
    for node, e in sorted(errs.items()):
        e.sort()
        med, p90 = e[len(e) // 2], e[int(0.9 * len(e))]
        medians.append(f"{node}:{med:.1f}")
        if not (med < 5 and p90 < 12):
            worst = sorted((c for c in deep if c["node"] == node), key=lambda c: -c["error_mm"])[:3]
            bad.append(f"node {node}: median {med:.1f}, p90 {p90:.1f} mm, worst " +
                       ", ".join(f"({c['u_mm']:.1f}, {c['v_mm']:.1f}) {c['error_mm']:.1f} mm "
                                 f"flags {c['flags']}" for c in worst))
    check("contacts in the page where the presses are, within the model's error", not bad and len(errs) >= 8,
          f"{len(errs)} patches, median mm by node {' '.join(medians)}" + (f"; {bad}" if bad else ""))
    # Two fingers on one patch: both shown at one instant (after one contacts message), each near
    # its press.
    deep_keys = {(c["track_id"], c["stamp_us"]) for c in deep}
    for node, ps in sorted(presses.items()):
        if len(ps) < 2:
            continue
        both = 0
        for shot in snapshots:
            mine = [c for c in shot if c["node"] == node and (c["track_id"], c["stamp_us"]) in deep_keys]
            near = [nearest_press(presses, node, c["u_mm"], c["v_mm"]) for c in mine]
            both += (len(mine) == 2 and {n[0] for n in near} == {0, 1} and max(n[3] for n in near) < 5)
        overlap_s = min(ps[0]["t1"], ps[1]["t1"]) - max(ps[0]["t0"], ps[1]["t0"])
        check(f"node {node}: the page shows both fingers at once", both >= 15,
              f"{both} instants with both (the presses overlap {overlap_s:.1f} s)")
    # A sliding press: the page draws its shear as an arrow along the slide.
    for node, p in sliding_presses(presses):
        along = slide_direction(build, f"{demo}/skin.yaml", node, p)
        arrows = [c for c in shown if c["node"] == node and c.get("shear_arrow_base")]
        cos_msg, cos_slide = [], []
        for c in arrows:
            a, s = c["shear_arrow_base"], c["shear_n"]
            na, ns = math.hypot(*a), math.hypot(*s)
            cos_msg.append(sum(x * y for x, y in zip(a, s)) / (na * ns))
            cos_slide.append(sum(x * y for x, y in zip(a, along)) / na)
        cos_slide.sort()
        check(f"node {node}: the page draws the sliding press's shear as an arrow along it",
              len(arrows) >= 3 and min(cos_msg) > 0.999 and cos_slide[len(cos_slide) // 2] > 0.9,
              f"{len(arrows)} arrows read back" + (
                  f", worst cosine to the message's shear {min(cos_msg):.4f}, median cosine to "
                  f"the slide {cos_slide[len(cos_slide) // 2]:.3f}" if arrows else ""))
    check("node 11 shown stale or offline after its daemon stopped",
          bool(states.get(11, set()) & {"stale", "offline"}), f"states seen {sorted(states.get(11, []))}")
    check("the other patches never shown offline",
          all("offline" not in v for n, v in states.items() if n != 11))
    check("the stalled banner once the host is gone", stalled_seen)
    shown = sorted(n for n, m in fields_max.items() if m >= 5)
    check("the sensors' field change of pressed patches reaches the page (from the bus)",
          len(shown) >= 8 and set(shown) <= set(presses), f"nodes {shown}")
    check("a pressed patch's sensor panel draws its heat map", panel is not None and panel[1] is not None
          and panel[1] >= 5, f"node {panel[0]}: max {panel[1]} uT" if panel else "never selected")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
