#!/usr/bin/python3
"""Load benchmark of the web view's page (view/web): does it keep up with the host's stream, and
at what frame rate?

Each row of the sweep is P patches and K contacts per message. For a row the benchmark generates
  - a scene of P patches on the project's robot (body_map/robots/skinbot.urdf), in skinbus-view's
    scene format (docs/view.md): cylinder sections around the forearms and upper arms, flat
    squares on the chest, back and pelvis, taken in turn from each of these places;
  - a stream of SECONDS seconds of JSON lines as skinbus-view sends them: `contacts` every 24 ms
    (41.7 Hz) with K contacts each, pressing and moving on the patches (each press lasts 2 s,
    then the next goes to another patch), placed on the moving links by the URDF's kinematics;
    `joint_state` at 30 Hz swinging both arms and the waist; `patch_status` once a second for
    all P patches (one patch degraded a second, a few events); `heartbeat` once a second. With
    K = 0 the contacts messages are empty (the host itself publishes nothing while no contact
    changes: that row costs a little more than an untouched robot);
and serves the page (view/web and its node_modules), the robot's folder, the scene at /api/scene
and the stream at /stream.jsonl on 127.0.0.1 (python's http.server, a free port). Headless
Chromium (tests/e2e/cdp.py: WebGL on SwiftShader, the CPU; a 1280 x 800 page, the 3D view beside
the side panel) opens /?replay=/stream.jsonl, which plays the stream at its recorded pace, and
the benchmark measures, from WARMUP seconds after the
replay starts until 1 s before the stream ends:
  fps                 requestAnimationFrame callbacks per second (a probe's own callback);
  longest frame gap   the longest time between two of them, ms (frames start on a 16.7 ms grid);
  long tasks          main-thread tasks over 50 ms (PerformanceObserver) and the longest: how
                      late a message can be handled (the replay, like the live socket, handles
                      every message due whenever the main thread is free);
  sent / handled      the stream's messages per second, and those the page handled per second
                      (its summary()'s message counts); it keeps up when it handles at least
                      98 % of the sent rate and, at the end, every message;
  handling            main-thread ms per second in the page's message handler, by message type
                      (summary().handling_ms: performance.now() around the handler; the page
                      is served cross-origin isolated, so that clock has 5 us steps, not 100);
  JSON parse          ms per second of stream to parse the messages (JSON.parse of every line
                      of the stream in the page, after the run, the median of 3 passes): a live
                      page parses each message as it arrives, the replay all of them up front;
  main thread         the renderer's main thread busy time (DevTools Performance domain,
                      TaskDuration), percent: the handler, three.js, style and layout;
  CPU                 CPU time of all Chromium's processes (renderer, GPU process, browser) and
                      of the GPU process alone (where SwiftShader draws), and the whole
                      machine's busy time, each in percent of one core (/proc).
Results: a table (Markdown) on stdout, OUT/view.csv, OUT/view.png (with matplotlib) and a
screenshot of each row's page, OUT/row_PxK.png. Progress on stderr. Exit status 1 when a row
could not be measured properly (patches not drawn, contacts not shown, page errors, a replay that
never finished).
"""
import argparse
import csv
import functools
import http.server
import itertools
import json
import math
import os
import shutil
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "tests", "e2e"))
import cdp  # noqa: E402

WEB_DIR = os.path.join(REPO, "view", "web")
ROBOT_DIR = os.path.join(REPO, "body_map", "robots")
ROBOT_FILE = "skinbot.urdf"

CONTACTS_PERIOD_US = 24_000     # 41.7 Hz
JOINT_STATE_HZ = 30
STATUS_PERIOD_US = 1_000_000    # patch_status and heartbeat
PRESS_S = 2.0                   # a contact presses one patch this long, then moves to another
GRID_POINTS = 15                # kSceneGridPoints, view/include/skinbus/view/scene_json.h
FIRST_STAMP_US = 1_795_000_000_000_000
TAIL_S = 1.0                    # the measurement ends this long before the stream does
OTHERS_NOTE_PCT = 20            # other processes' CPU (% of a core) worth a note in the progress
DEFAULT_ROWS = ["12x0", "12x2", "64x0", "64x8", "64x64"]


def log(message):
    print("bench_view: " + message, file=sys.stderr, flush=True)


# -- geometry ------------------------------------------------------------------------------------

def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def mat_vec(m, v):
    return [m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] for i in range(3)]


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def rotation_axis_angle(axis, angle):
    x, y, z = axis
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]


def rotation_rpy(roll, pitch, yaw):
    """URDF's roll-pitch-yaw: Rz(yaw) Ry(pitch) Rx(roll)."""
    return mat_mul(rotation_axis_angle([0, 0, 1], yaw),
                   mat_mul(rotation_axis_angle([0, 1, 0], pitch),
                           rotation_axis_angle([1, 0, 0], roll)))


def numbers(element, attribute, default):
    """A URDF attribute's numbers; default (URDF's) when the element or attribute is absent."""
    text = default if element is None else element.get(attribute, default)
    return [float(x) for x in text.split()]


class Robot:
    """A URDF's kinematic tree (revolute, continuous and fixed joints): every link's pose in the
    root link's frame, the base frame the host's contact positions are in, in mm."""

    def __init__(self, path):
        root = ET.parse(path).getroot()
        self.links = {link.get("name") for link in root.findall("link")}
        joints = []
        for j in root.findall("joint"):
            kind = j.get("type")
            if kind not in ("revolute", "continuous", "fixed"):
                raise ValueError(f"{path}: joint {j.get('name')}: type {kind} is not supported")
            joints.append({
                "name": j.get("name"), "movable": kind != "fixed",
                "parent": j.find("parent").get("link"), "child": j.find("child").get("link"),
                "rotation": rotation_rpy(*numbers(j.find("origin"), "rpy", "0 0 0")),
                "translation": [x * 1000 for x in numbers(j.find("origin"), "xyz", "0 0 0")],
                "axis": numbers(j.find("axis"), "xyz", "1 0 0"),
            })
        children = {j["child"] for j in joints}
        (self.root,) = self.links - children
        # Parents before children: one pass places every link.
        self.joints, placed = [], {self.root}
        while len(self.joints) < len(joints):
            ready = [j for j in joints if j["parent"] in placed and j["child"] not in placed]
            if not ready:
                raise ValueError(f"{path}: joints not connected to the root {self.root}")
            self.joints += ready
            placed.update(j["child"] for j in ready)
        self.movable = [j["name"] for j in joints if j["movable"]]   # the URDF's order

    def poses(self, q):
        """link -> (rotation, translation in mm) in the root's frame; q: joint -> rad (else 0)."""
        poses = {self.root: ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0.0, 0.0, 0.0])}
        for j in self.joints:
            rotation, translation = poses[j["parent"]]
            local = j["rotation"]
            if j["movable"]:
                local = mat_mul(local, rotation_axis_angle(j["axis"], q.get(j["name"], 0.0)))
            offset = mat_vec(rotation, j["translation"])
            poses[j["child"]] = (mat_mul(rotation, local),
                                 [translation[i] + offset[i] for i in range(3)])
        return poses


class Patch:
    """One patch on its link: a flat square or a cylinder section (axis along the patch's v),
    by its centre on the skin, its outward normal and its v axis in the link's frame, as
    body_map's surface mapping (docs/body_map.md)."""

    def __init__(self, link, kind, centre, normal, v_axis, size_u, size_v, radius=0.0):
        self.link, self.kind, self.centre, self.normal = link, kind, centre, normal
        self.v_axis, self.u_axis = v_axis, cross(v_axis, normal)
        self.size_u, self.size_v, self.radius = size_u, size_v, radius
        self.node = self.hardware_uid = self.interface = None   # given when the scene is made

    def surface(self, u, v):
        """The skin point (u, v) and its outward normal in the link's frame (mm)."""
        if self.kind == "flat":
            local, normal = [u, v, 0.0], [0.0, 0.0, 1.0]
        else:
            theta = u / self.radius
            local = [self.radius * math.sin(theta), v, self.radius * (math.cos(theta) - 1)]
            normal = [math.sin(theta), 0.0, math.cos(theta)]
        frame = (self.u_axis, self.v_axis, self.normal)
        point = [self.centre[i] + sum(frame[k][i] * local[k] for k in range(3)) for i in range(3)]
        return point, [sum(frame[k][i] * normal[k] for k in range(3)) for i in range(3)]

    def scene_entry(self):
        points = []
        for i in range(GRID_POINTS):
            u = -self.size_u / 2 + i * self.size_u / (GRID_POINTS - 1)
            for j in range(GRID_POINTS):
                v = -self.size_v / 2 + j * self.size_v / (GRID_POINTS - 1)
                points.append(rounded(self.surface(u, v)[0], 3))
        return {"node": self.node, "hardware_uid": self.hardware_uid, "link": self.link,
                "kind": self.kind, "size_u_mm": self.size_u, "size_v_mm": self.size_v,
                "radius_mm": self.radius, "centre_mm": rounded(self.centre, 3),
                "normal": rounded(self.normal, 6),
                "grid": {"nu": GRID_POINTS, "nv": GRID_POINTS, "points_mm": points}}


def rounded(values, digits):
    return [round(x, digits) for x in values]


def patch_places():
    """Where patches fit on skinbot (the facts of its URDF's header comment), by place: 12
    around each forearm (radius 45 mm about x, x in [20, 250]), 12 around each upper arm (40 mm
    about z, z in [-250, -30]), 20 on the chest (x = 110 mm, y in [-160, 160], z in [20, 460])
    and on the back of torso_link, 3 on the front and on the back of the pelvis (a box 200 x
    300 x 140 mm)."""
    places = []
    for side in ("left", "right"):
        forearm, upper = [], []
        for quarter in range(4):
            phi = math.pi / 4 + quarter * math.pi / 2
            c, s = math.cos(phi), math.sin(phi)
            for x in (65, 135, 205):
                forearm.append(Patch(f"{side}_forearm_link", "cylinder", [x, 45 * c, 45 * s],
                                     [0, c, s], [1, 0, 0], 68, 66, 45))
            for z in (-70, -140, -210):
                upper.append(Patch(f"{side}_upper_arm_link", "cylinder", [40 * c, 40 * s, z],
                                   [c, s, 0], [0, 0, 1], 60, 66, 40))
        places += [forearm, upper]
    for x, sign in ((110, 1), (-110, -1)):
        places.append([Patch("torso_link", "flat", [x, y, z], [sign, 0, 0], [0, 0, 1], 76, 80)
                       for y in (-120, -40, 40, 120) for z in (60, 150, 240, 330, 420)])
    for x, sign in ((100, 1), (-100, -1)):
        places.append([Patch("pelvis", "flat", [x, y, 0], [sign, 0, 0], [0, 0, 1], 90, 120)
                       for y in (-100, 0, 100)])
    return places


PATCH_CAPACITY = sum(len(place) for place in patch_places())


def make_patches(count, robot):
    """count (at most PATCH_CAPACITY) patches, one from each place in turn; nodes 1..count on
    two buses."""
    in_turn = itertools.chain.from_iterable(itertools.zip_longest(*patch_places()))
    patches = [p for p in in_turn if p is not None][:count]
    for i, p in enumerate(patches):
        if p.link not in robot.links:
            raise ValueError(f"link {p.link} is not in the robot")
        p.node = i + 1
        p.hardware_uid = f"5b{p.node:014x}"
        p.interface = "can0" if i < (count + 1) // 2 else "can1"
    return patches


# -- stream --------------------------------------------------------------------------------------

def joint_positions(t):
    """The waist and both arms swinging, rad, t seconds into the stream."""
    q = {"waist_yaw_joint": 0.25 * math.sin(2 * math.pi * t / 8)}
    for side, outward, phase in (("left", 1, 0.0), ("right", -1, math.pi / 2)):
        def wave(period):
            return math.sin(2 * math.pi * t / period + phase)
        q[f"{side}_shoulder_pitch_joint"] = -0.4 + 0.4 * wave(5)
        q[f"{side}_shoulder_roll_joint"] = outward * (0.25 + 0.15 * wave(7))
        q[f"{side}_shoulder_yaw_joint"] = 0.3 * wave(6)
        q[f"{side}_elbow_joint"] = 0.7 + 0.5 * wave(4)
        q[f"{side}_wrist_joint"] = 0.8 * wave(3)
    return q


def contacts_message(t, stamp_us, patches, count, robot):
    """count contacts at t: contact k presses for PRESS_S (the contacts staggered), moving round
    a small ellipse on its patch, then the next press (a new track) on another patch."""
    poses = robot.poses(joint_positions(t))
    contacts = []
    for k in range(count):
        shifted = t + k * PRESS_S / count
        press = int(shifted // PRESS_S)
        phase = shifted / PRESS_S - press        # 0..1 through the press
        patch = patches[(k + press * count) % len(patches)]
        angle = 2 * math.pi * phase + k
        u, v = 0.25 * patch.size_u * math.cos(angle), 0.25 * patch.size_v * math.sin(angle)
        point, normal = patch.surface(u, v)
        rotation, translation = poses[patch.link]
        position = [a + b for a, b in zip(mat_vec(rotation, point), translation)]
        depth = 0.5 + 2.5 * math.sin(math.pi * phase)
        contacts.append({
            "track_id": 1 + press * count + k, "position_mm": rounded(position, 2),
            "normal": rounded(mat_vec(rotation, normal), 4), "depth_mm": round(depth, 3),
            "force_n": round(2.4 * depth, 3), "node": patch.node,
            "hardware_uid": patch.hardware_uid, "link": patch.link, "u_mm": round(u, 2),
            "v_mm": round(v, 2), "uncertainty_mm": 0.9, "patch_count": 1,
            "first_seen_us": stamp_us - round(phase * PRESS_S * 1e6), "flags": []})
    return {"type": "contacts", "stamp_us": stamp_us, "base_frame": robot.root,
            "contacts": contacts}


def patch_status_message(second, stamp_us, patches):
    """Every patch's status at the second'th second: one patch degraded this second (the last
    one back online), a sequence gap every fourth second."""
    n = len(patches)
    degraded, recovered = patches[(7 * second) % n], patches[(7 * (second - 1)) % n]
    events = [{"time_us": stamp_us, "event": "degraded", "node": degraded.node,
               "hardware_uid": degraded.hardware_uid, "detail": "sensor 2 faulty"}]
    if second > 0 and recovered is not degraded:
        events.append({"time_us": stamp_us, "event": "online", "node": recovered.node,
                       "hardware_uid": recovered.hardware_uid, "detail": "faults cleared"})
    if second % 4 == 3:
        gap = patches[(5 * second + 1) % n]
        events.append({"time_us": stamp_us, "event": "sequence_gap", "node": gap.node,
                       "hardware_uid": gap.hardware_uid, "detail": "3 samples lost"})
    entries = []
    for p in patches:
        bad = p is degraded
        uptime = 600 + second
        entries.append({
            "node": p.node, "hardware_uid": p.hardware_uid, "interface": p.interface,
            "link": p.link, "state": "degraded" if bad else "online", "node_state": 2 if bad else 1,
            "node_mode": 2, "fault_mask": 4 if bad else 0, "uptime_s": uptime, "reboots": 0,
            "samples": 100 * uptime + p.node, "samples_lost": 3 * (second // 4),
            "contacts": 5 * second // p.node, "clock_offset_us": 1200 + p.node,
            "clock_drift_ppm": 3.5, "last_heard_us": stamp_us - 4000, "duplicate_id": False,
            "detail": "sensor 2 faulty" if bad else ""})
    return {"type": "patch_status", "stamp_us": stamp_us, "patches": entries, "events": events}


def make_stream(seconds, patches, contacts_per_message, robot):
    """The stream's JSON lines: hello, then every message in stamp order."""
    end_us = round(seconds * 1e6)
    timed = []   # (stamp, kind order, message)
    for stamp in range(0, end_us, CONTACTS_PERIOD_US):
        timed.append((stamp, 0, contacts_message(stamp / 1e6, FIRST_STAMP_US + stamp, patches,
                                                 contacts_per_message, robot)))
    for i in range(math.ceil(seconds * JOINT_STATE_HZ)):
        stamp = round(i * 1e6 / JOINT_STATE_HZ)
        q = joint_positions(stamp / 1e6)
        timed.append((stamp, 1, {"type": "joint_state", "stamp_us": FIRST_STAMP_US + stamp,
                                 "names": robot.movable,
                                 "positions": [round(q.get(n, 0.0), 6) for n in robot.movable]}))
    for second, stamp in enumerate(range(0, end_us, STATUS_PERIOD_US)):
        timed.append((stamp, 2, patch_status_message(second, FIRST_STAMP_US + stamp, patches)))
        timed.append((stamp, 3, {"type": "heartbeat", "stamp_us": FIRST_STAMP_US + stamp,
                                 "host_age_ms": 12}))
    timed.sort(key=lambda m: m[:2])
    lines = [json.dumps({"type": "hello", "read_only": True})]
    lines += [json.dumps(m, separators=(",", ":")) for _, _, m in timed]
    return lines, len(timed)


# -- serving -------------------------------------------------------------------------------------

class Handler(http.server.SimpleHTTPRequestHandler):
    """Files of the served folder, quietly. Cross-origin isolated (every file is same-origin):
    the page's performance.now() then has 5 us steps rather than 100 us."""

    def end_headers(self):
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def log_message(self, *args):
        pass


def serve_folder():
    """A temporary folder laid out as skinbus-view serves (the page's files, node_modules, the
    robot's folder under /robot/, the scene at /api/scene) and a server for it on 127.0.0.1 on
    a free port: (folder, server)."""
    folder = tempfile.mkdtemp(prefix="bench-view-")
    for name in os.listdir(WEB_DIR):
        if name.endswith((".html", ".js", ".css")) or name == "node_modules":
            os.symlink(os.path.join(WEB_DIR, name), os.path.join(folder, name))
    os.symlink(ROBOT_DIR, os.path.join(folder, "robot"))
    os.mkdir(os.path.join(folder, "api"))
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(Handler, directory=folder))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return folder, server


# -- measuring -----------------------------------------------------------------------------------

# The probe: its own requestAnimationFrame callback counts frames and the longest gap between
# them, a PerformanceObserver the main thread's long tasks (over 50 ms) and the longest;
# snapshot() reads them with the page's summary() in one go (reset: the longest ones from now).
PROBE_JS = """
window.benchProbe = (() => {
  let frames = 0, lastMs = null, longestGapMs = 0, longTasks = 0, longestTaskMs = 0;
  new PerformanceObserver((list) => {
    for (const task of list.getEntries()) {
      longTasks++;
      longestTaskMs = Math.max(longestTaskMs, task.duration);
    }
  }).observe({ type: 'longtask' });
  const tick = (t) => {
    if (lastMs !== null) longestGapMs = Math.max(longestGapMs, t - lastMs);
    lastMs = t;
    frames++;
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
  return {
    snapshot(reset) {
      const s = window.skinbusView.summary();
      const out = {
        now_ms: performance.now(), frames, longest_gap_ms: longestGapMs,
        long_tasks: longTasks, longest_task_ms: longestTaskMs,
        messages: s.messages, handling_ms: s.handling_ms,
        patches_drawn: s.patches.filter((p) => p.drawn).length, contacts: s.contacts.length,
        errors: s.errors, replay: s.replay, isolated: window.crossOriginIsolated,
      };
      if (reset) longestGapMs = longestTaskMs = 0;
      return out;
    },
  };
})();
true
"""

PARSE_JS = """
(async () => {
  const lines = (await (await fetch('/stream.jsonl')).text()).split('\\n').filter((l) => l);
  const passes = [];
  for (let pass = 0; pass < 3; pass++) {
    const startMs = performance.now();
    for (const line of lines) JSON.parse(line);
    passes.push(performance.now() - startMs);
  }
  return passes.sort((a, b) => a - b)[1];
})()
"""

REPLAY_STARTED = "window.benchProbe && window.skinbusView.summary().replay !== null"
REPLAY_ENDED = "window.skinbusView.summary().replay.ended"
TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def cpu_ticks(session):
    """CPU time so far, in clock ticks: the whole machine's busy time ("machine"), the
    processes' of the session ("chromium") and of its GPU process ("gpu")."""
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:9]]   # user .. steal
    ticks = {"machine": sum(fields) - fields[3] - fields[4], "chromium": 0, "gpu": 0}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as f:
                stat = f.read()
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                gpu = b"--type=gpu-process" in f.read()
        except OSError:
            continue
        rest = stat[stat.rfind(")") + 2:].split()   # from field 3, the state
        if int(rest[3]) == session:
            used = int(rest[11]) + int(rest[12])     # utime + stime
            ticks["chromium"] += used
            ticks["gpu"] += used if gpu else 0
    return ticks


def sample(browser, reset=False):
    """The page's probe, the renderer's metrics and the CPU counters at one moment."""
    metrics = {m["name"]: m["value"] for m in browser.send("Performance.getMetrics")["metrics"]}
    page = browser.evaluate(f"window.benchProbe.snapshot({'true' if reset else 'false'})")
    return {"page": page, "metrics": metrics, "cpu": cpu_ticks(browser.pid),
            "wall": time.monotonic()}


def sleep_until(t):
    time.sleep(max(0.0, t - time.monotonic()))


def write_row_files(folder, seconds, patches_count, contacts_count, robot):
    """The row's scene and stream in the served folder: (messages with a stamp, MB of stream)."""
    patches = make_patches(patches_count, robot)
    scene = {"type": "scene", "robot_url": f"/robot/{ROBOT_FILE}", "base_frame": robot.root,
             "read_only": True, "patches": [p.scene_entry() for p in patches]}
    with open(os.path.join(folder, "api", "scene"), "w") as f:
        json.dump(scene, f, separators=(",", ":"))
    lines, sent = make_stream(seconds, patches, contacts_count, robot)
    stream_path = os.path.join(folder, "stream.jsonl")
    with open(stream_path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return sent, os.path.getsize(stream_path) / 1e6


def measure_page(args, port, label, screenshot):
    """Plays the stream in a new headless Chromium: the samples at the start and the end of the
    measurement, the page's final snapshot, the parse time of the whole stream (ms), the page's
    errors, and problems met."""
    problems = []
    with cdp.Browser(chromium=args.chromium) as browser:
        browser.send("Performance.enable")
        browser.open(f"http://127.0.0.1:{port}/?replay=/stream.jsonl")
        browser.evaluate(PROBE_JS)
        browser.wait_for(REPLAY_STARTED, timeout_s=120, interval_s=0.05)
        started = time.monotonic()
        log(f"{label}: replay started; measuring from {args.warmup:g} s to "
            f"{args.seconds - TAIL_S:g} s")
        sleep_until(started + args.warmup)
        first = sample(browser, reset=True)
        sleep_until(started + args.seconds - TAIL_S)
        last = sample(browser)
        try:
            browser.wait_for(REPLAY_ENDED, timeout_s=TAIL_S + 30)
        except cdp.CdpError:
            problems.append("the replay did not finish within 30 s of the stream's end")
        browser.screenshot(screenshot)
        parse_ms = browser.evaluate(PARSE_JS, timeout_s=60)
        final = browser.evaluate("window.benchProbe.snapshot(false)")
        errors = final["errors"] + browser.console_errors()
    if errors:
        problems.append("page errors: " + "; ".join(errors)[:500])
    return first, last, final, parse_ms, problems


def run_row(args, folder, port, patches_count, contacts_count, robot):
    """One row of the sweep: (its figures, the problems met measuring it)."""
    label = f"{patches_count} patches, {contacts_count} contacts/message"
    sent, size_mb = write_row_files(folder, args.seconds, patches_count, contacts_count, robot)
    log(f"{label}: {sent} messages, {size_mb:.1f} MB of stream; opening the page")
    first, last, final, parse_ms, problems = measure_page(
        args, port, label, os.path.join(args.out, f"row_{patches_count}x{contacts_count}.png"))

    a, b = first["page"], last["page"]
    window_s = (b["now_ms"] - a["now_ms"]) / 1000

    def per_s(key, kind=None):
        kinds = [kind] if kind else b[key].keys()
        return sum(b[key].get(k, 0) - a[key].get(k, 0) for k in kinds) / window_s

    metric_s = last["metrics"]["Timestamp"] - first["metrics"]["Timestamp"]

    def metric(name):
        return (last["metrics"][name] - first["metrics"][name]) / metric_s

    def cpu_pct(name):
        ticks = last["cpu"][name] - first["cpu"][name]
        return round(100 * ticks / TICKS_PER_S / (last["wall"] - first["wall"]), 1)

    sent_per_s = sent / args.seconds
    handled_per_s = per_s("messages")
    all_handled = final["replay"]["position"] == final["replay"]["total"]
    row = {
        "patches": patches_count,
        "contacts_per_message": contacts_count,
        "window_s": round(window_s, 2),
        "fps": round((b["frames"] - a["frames"]) / window_s, 1),
        "longest_frame_gap_ms": round(b["longest_gap_ms"], 1),
        "long_tasks": b["long_tasks"] - a["long_tasks"],
        "longest_task_ms": round(b["longest_task_ms"], 1),
        "sent_per_s": round(sent_per_s, 2),
        "handled_per_s": round(handled_per_s, 2),
        "kept_up": handled_per_s >= 0.98 * sent_per_s and all_handled,
        "handling_ms_per_s": round(per_s("handling_ms"), 3),
        "contacts_ms_per_s": round(per_s("handling_ms", "contacts"), 3),
        "patch_status_ms_per_s": round(per_s("handling_ms", "patch_status"), 3),
        "joint_state_ms_per_s": round(per_s("handling_ms", "joint_state"), 3),
        "parse_ms_per_s": round(parse_ms / args.seconds, 3),
        "main_thread_busy_pct": round(100 * metric("TaskDuration"), 1),
        "style_layout_ms_per_s": round(
            1000 * (metric("RecalcStyleDuration") + metric("LayoutDuration")), 2),
        "chromium_cpu_pct": cpu_pct("chromium"),
        "gpu_process_cpu_pct": cpu_pct("gpu"),
        "machine_cpu_pct": cpu_pct("machine"),
    }
    if b["patches_drawn"] != patches_count:
        problems.append(f"{b['patches_drawn']} of {patches_count} patches drawn")
    if b["contacts"] != contacts_count:
        problems.append(f"{b['contacts']} contacts shown, {contacts_count} sent")
    if not b["isolated"]:
        problems.append("the page is not cross-origin isolated (a coarse clock)")
    if not all_handled:
        problems.append(f"{final['replay']['position']} of {final['replay']['total']} "
                        "messages handled")
    others = row["machine_cpu_pct"] - row["chromium_cpu_pct"]
    log(f"{label}: {row['fps']} fps, longest gap {row['longest_frame_gap_ms']} ms, "
        f"messages {row['sent_per_s']}/s sent, {row['handled_per_s']}/s handled, "
        f"handling {row['handling_ms_per_s']} ms/s"
        + (f"\n  note: other processes used {others:.0f} % of a core meanwhile"
           if others > OTHERS_NOTE_PCT else "")
        + "".join(f"\n  PROBLEM: {p}" for p in problems))
    return row, problems


# -- results -------------------------------------------------------------------------------------

TABLE = [  # header, CSV column or function of the row
    ("patches", "patches"),
    ("contacts / message", "contacts_per_message"),
    ("fps", "fps"),
    ("longest frame gap (ms)", "longest_frame_gap_ms"),
    ("main-thread tasks over 50 ms (longest, ms)",
     lambda r: f"{r['long_tasks']}" + (f" ({r['longest_task_ms']:g})" if r["long_tasks"] else "")),
    ("messages sent / handled per s", lambda r: f"{r['sent_per_s']:g} / {r['handled_per_s']:g}"),
    ("keeps up", lambda r: "yes" if r["kept_up"] else "no"),
    ("handling (ms/s)", "handling_ms_per_s"),
    ("of which contacts / patch_status / joint_state (ms/s)",
     lambda r: f"{r['contacts_ms_per_s']:.2f} / {r['patch_status_ms_per_s']:.2f} / "
               f"{r['joint_state_ms_per_s']:.2f}"),
    ("JSON parse (ms/s)", "parse_ms_per_s"),
    ("renderer main thread busy (%)", "main_thread_busy_pct"),
    ("Chromium CPU, of which GPU process (% of a core)",
     lambda r: f"{r['chromium_cpu_pct']:g}, {r['gpu_process_cpu_pct']:g}"),
    ("whole machine busy (% of a core)", "machine_cpu_pct"),
]


def print_table(rows):
    print("| " + " | ".join(h for h, _ in TABLE) + " |")
    print("|" + "---:|" * len(TABLE))
    for r in rows:
        cells = [c(r) if callable(c) else f"{r[c]:g}" if isinstance(r[c], float) else str(r[c])
                 for _, c in TABLE]
        print("| " + " | ".join(cells) + " |")


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def plot(path, rows, seconds):
    try:
        import matplotlib
    except ImportError:
        log("matplotlib is not installed: no plot")
        return
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['patches']} patches\n{r['contacts_per_message']} contacts" for r in rows]
    x = range(len(rows))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    fps = [r["fps"] for r in rows]
    left.bar(x, fps, color="tab:blue")
    for i, r in enumerate(rows):
        left.text(i, fps[i], f"{fps[i]:.1f}\n(gap {r['longest_frame_gap_ms']:.0f} ms)",
                  ha="center", va="bottom", fontsize=8)
    left.set_ylim(0, max(fps) * 1.25)
    left.set_ylabel("frames per second")
    left.set_title("frame rate (headless Chromium, WebGL on SwiftShader)")
    handling_x = [i - 0.15 for i in x]
    bottom = [0.0] * len(rows)
    for key, name, colour in (("contacts_ms_per_s", "contacts", "tab:orange"),
                              ("patch_status_ms_per_s", "patch_status", "tab:green"),
                              ("joint_state_ms_per_s", "joint_state", "tab:purple")):
        values = [r[key] for r in rows]
        right.bar(handling_x, values, width=0.5, bottom=bottom, color=colour,
                  label=f"handling {name}")
        bottom = [b + v for b, v in zip(bottom, values)]
    others = [r["handling_ms_per_s"] - b for r, b in zip(rows, bottom)]
    right.bar(handling_x, others, width=0.5, bottom=bottom, color="tab:gray",
              label="handling hello, heartbeat")
    parse = [r["parse_ms_per_s"] for r in rows]
    right.bar([i + 0.25 for i in x], parse, width=0.25, color="white", edgecolor="k",
              hatch="//", label="JSON parse (a live page's)")
    for i, r in enumerate(rows):
        right.text(handling_x[i], r["handling_ms_per_s"], f"{r['handling_ms_per_s']:.1f}",
                   ha="center", va="bottom", fontsize=8)
    right.set_ylim(0, max(r["handling_ms_per_s"] for r in rows) * 1.4)
    right.legend(fontsize=8, loc="upper left")
    right.set_ylabel("main-thread ms per second")
    right.set_title("the page's message handling (of 1000 ms/s)")
    for ax in (left, right):
        ax.set_xticks(list(x))
        ax.set_xticklabels(labels, fontsize=8)
    fig.suptitle(f"skinbus view page under load: {seconds:g} s streams, contacts at 41.7 Hz, "
                 "joint states at 30 Hz, status at 1 Hz")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_row(text):
    try:
        patches, contacts = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected PATCHESxCONTACTS, e.g. 64x8")
    if not 1 <= patches <= PATCH_CAPACITY or contacts < 0:
        raise argparse.ArgumentTypeError(
            f"{text!r}: 1 to {PATCH_CAPACITY} patches (what fits on the robot), 0 or more contacts")
    return patches, contacts


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", nargs="+", type=parse_row, metavar="PxK",
                    default=[parse_row(r) for r in DEFAULT_ROWS],
                    help="rows of the sweep: P patches, K contacts per message "
                    f"(default {' '.join(DEFAULT_ROWS)})")
    ap.add_argument("--seconds", type=float, default=15.0,
                    help="length of each row's stream, s (default 15)")
    ap.add_argument("--warmup", type=float, default=3.0,
                    help="seconds of the stream before the measurement starts (default 3)")
    ap.add_argument("--out", default="out/bench_view",
                    help="folder for view.csv, view.png and the screenshots "
                    "(default out/bench_view)")
    ap.add_argument("--chromium", default="chromium", help="the browser (default chromium)")
    args = ap.parse_args()
    if args.seconds - TAIL_S - args.warmup < 2:
        ap.error(f"--seconds must exceed --warmup by at least {TAIL_S + 2:g} s")
    os.makedirs(args.out, exist_ok=True)

    robot = Robot(os.path.join(ROBOT_DIR, ROBOT_FILE))
    folder, server = serve_folder()
    port = server.server_address[1]
    log(f"serving {folder} on http://127.0.0.1:{port}/")
    rows, failed = [], False
    try:
        for patches_count, contacts_count in args.rows:
            try:
                row, problems = run_row(args, folder, port, patches_count, contacts_count, robot)
            except cdp.CdpError as e:
                log(f"{patches_count}x{contacts_count}: not measured: {e}")
                failed = True
                continue
            rows.append(row)
            failed |= bool(problems)
    finally:
        server.shutdown()
        server.server_close()
        shutil.rmtree(folder)
    if not rows:
        return 1
    print_table(rows)
    write_csv(os.path.join(args.out, "view.csv"), rows)
    plot(os.path.join(args.out, "view.png"), rows, args.seconds)
    log(f"wrote {args.out}/view.csv, view.png and row_*.png")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
