#!/usr/bin/python3
"""Checks contacts placed with joint states from DDS while the stream runs, stops and resumes.

  check_joint_stream.py CONTACTS --locate BIN --map MAP --press "NODE U_MM V_MM"
      --trajectory CSV --start US --stop US [--hold CSV --restart US] [--reference HOST_JSONL]

CONTACTS: JSON lines of skinbus-listen --status (or skinbus-host --json --json-status). The
first joint-state stream publishes --trajectory from --start (its time zero) to --stop (its last
sample), both CLOCK_REALTIME microseconds; a second one, if given, holds the pose of --hold from
--restart on. Per contact array, by its stamp S:

  S < start - 0.1 s              flagged no_kinematics (no joint state yet)
  start + 0.5 s <= S <= stop     neither no_kinematics nor stale_kinematics; placed where
                                 skinbus-locate puts the press at trajectory time S - start
                                 (the nearest within +-0.05 s: the host and the publisher
                                 sample at different moments)
  S <= stop                      never stale_kinematics
  stop + 0.35 s < S < restart    stale_kinematics (0.25 s in the host, 0.1 s for delivery), at
                                 the last pose the stream gave
  S > restart + 0.3 s            not stale again, at the --hold pose

Positions: the contacts at least 1 mm deep, median error < --tolerance (6 mm), p90 < twice it.
A control shows the check can see a frozen arm: while streaming, the median distance to the
pose at time zero must be above twice the tolerance. The status must carry exactly one
kinematics_stale event (within 1 s after the stop) and, with --restart, exactly one
kinematics_fresh (within 0.5 s after it); events of the host's end-of-log flush (stamped with
the final status) are not counted. Prints PASS/FAIL lines; exit 1 on any FAIL.
"""
import argparse
import bisect
import json
import math
import subprocess
import sys


def read_lines(path):
    contacts, status = [], []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line.startswith("{"):
                continue
            j = json.loads(line)
            if j.get("type") == "contacts":
                contacts.append(j)
            elif j.get("type") == "patch_status":
                status.append(j)
    return contacts, status


def trajectory_end(path):
    last = 0.0
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#") and not line.startswith("time_s"):
                last = float(line.split(",")[0])
    return last


def locate(a, joints, times):
    """(link, point) of the press (node, u, v) at each time of `times`, from one skinbus-locate
    run (a "T NODE U V" line per time)."""
    query = "".join(f"{t:.6f} {a.press}\n" for t in times)
    out = subprocess.run([a.locate, "--map", a.map, "--joints", joints, "-"], input=query,
                         capture_output=True, text=True, check=True).stdout.splitlines()
    return [(f[1], tuple(float(x) for x in f[2:5])) for f in (line.split() for line in out)]


class Truth:
    """Where skinbus-locate puts the press (node, u, v) along a trajectory, on a 10 ms grid."""

    def __init__(self, a, joints, end_s):
        self.step = 0.01
        self.end_s = end_s
        n = int(round(end_s / self.step)) + 1
        located = locate(a, joints, [i * self.step for i in range(n)])
        self.points = [point for _, point in located]
        self.link = located[0][0]

    def at(self, t):
        t = min(max(t, 0.0), self.end_s)
        i = min(int(t / self.step), len(self.points) - 1)
        if i + 1 >= len(self.points):
            return self.points[-1]
        w = (t - i * self.step) / self.step
        p, q = self.points[i], self.points[i + 1]
        return tuple(p[k] + w * (q[k] - p[k]) for k in range(3))

    def error(self, pos, t, window):
        # The smallest distance within +-window, in 5 ms steps.
        steps = int(round(window / 0.005))
        return min(math.dist(pos, self.at(t + k * 0.005)) for k in range(-steps, steps + 1))


def stats(errs):
    e = sorted(errs)
    if not e:
        return float("nan"), float("nan")
    return e[len(e) // 2], e[int(0.9 * len(e))]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("contacts")
    ap.add_argument("--reference", help="skinbus-host --json output: received >= 90 %% of it")
    ap.add_argument("--locate", required=True, help="the skinbus-locate binary")
    ap.add_argument("--map", required=True)
    ap.add_argument("--press", required=True, help='"NODE U_MM V_MM" of the press')
    ap.add_argument("--trajectory", required=True)
    ap.add_argument("--start", type=int, required=True, help="time zero of the stream, us")
    ap.add_argument("--stop", type=int, required=True, help="its last sample's stamp, us")
    ap.add_argument("--hold", help="trajectory of the restarted stream")
    ap.add_argument("--restart", type=int, help="time zero of the restarted stream, us")
    ap.add_argument("--tolerance", type=float, default=6.0, help="median position error, mm")
    ap.add_argument("--min-per-phase", type=int, default=15,
                    help="contacts needed in each phase")
    a = ap.parse_args()
    if (a.hold is None) != (a.restart is None):
        ap.error("--hold and --restart go together")
    node = int(a.press.split()[0])
    got, status = read_lines(a.contacts)
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    if a.reference:
        ref, _ = read_lines(a.reference)
        check("the subscriber received what the host published", len(got) >= 0.9 * len(ref),
              f"{len(got)} of {len(ref)}")
    stream = Truth(a, a.trajectory, trajectory_end(a.trajectory))
    last_pose = stream.at(stream.end_s)
    start_pose = stream.at(0.0)
    hold_pose = locate(a, a.hold, [0.0])[0][1] if a.hold else None
    restart = a.restart if a.restart is not None else float("inf")
    us = 1e-6

    early, streaming, stopped, resumed = [], [], [], []
    wrong, stale_while_streaming = [], []
    for arr in got:
        s = arr["stamp_us"]
        for c in arr["contacts"]:
            if c["node"] != node or c["link"] != stream.link or c["track_id"] == 0:
                wrong.append(c["node"])
            flags = set(c["flags"])
            if s <= a.stop and "stale_kinematics" in flags:
                stale_while_streaming.append((s - a.start) * us)
            if s < a.start - 100_000:
                early.append(flags)
            elif a.start + 500_000 <= s <= a.stop:
                streaming.append((s, c, flags))
            elif a.stop + 350_000 < s < restart:
                stopped.append((s, c, flags))
            elif s > restart + 300_000:
                resumed.append((s, c, flags))
    check(f"contacts only on node {node} ({stream.link}), tracked", not wrong,
          f"bad nodes {sorted(set(wrong))}" if wrong else f"{len(got)} arrays")
    check("before the first joint state: flagged no_kinematics",
          all("no_kinematics" in f for f in early), f"{len(early)} contacts")
    check("no stale_kinematics while the stream runs", not stale_while_streaming,
          f"at {[round(t, 3) for t in stale_while_streaming[:5]]} s" if stale_while_streaming
          else "")

    def phase(name, items, want_stale, pose_of, control=None):
        flagged = [(round((s - a.start) * us, 3), sorted(f)) for s, _, f in items
                   if ("stale_kinematics" in f) != want_stale or "no_kinematics" in f]
        check(f"{name}: {len(items)} contacts, " +
              ("all" if want_stale else "none") + " flagged stale_kinematics, none no_kinematics",
              len(items) >= a.min_per_phase and not flagged,
              f"{len(flagged)} wrong, e.g. (s after time zero, flags) {flagged[:3]}"
              if flagged else "")
        errs, ctrl = [], []
        for s, c, _ in items:
            if c["depth_mm"] >= 1.0:
                errs.append(pose_of(s, c["position_mm"]))
                if control is not None:
                    ctrl.append(math.dist(c["position_mm"], control))
        med, p90 = stats(errs)
        check(f"{name}: positions", len(errs) >= a.min_per_phase and med < a.tolerance
              and p90 < 2 * a.tolerance,
              f"{len(errs)} contacts >= 1 mm deep, median {med:.2f} mm, p90 {p90:.2f} mm")
        if control is not None:
            cmed, _ = stats(ctrl)
            check(f"{name}: the arm moved (control: distance to the pose at time zero)",
                  cmed > 2 * a.tolerance, f"median {cmed:.1f} mm")

    phase("while streaming", streaming, False,
          lambda s, p: stream.error(p, (s - a.start) * us, 0.05), control=start_pose)
    phase("after the stream stopped", stopped, True,
          lambda s, p: math.dist(p, last_pose))
    if a.hold:
        phase("after the stream resumed", resumed, False,
              lambda s, p: math.dist(p, hold_pose))

    # The host ends a log by running the pipeline once more 0.5 s past its end, so that held
    # contacts run out; the joint states look 0.5 s old to that last tick, which reports
    # kinematics_stale stamped with the final status. Such events are listed, not counted.
    events = [e for st in status for e in st["events"]]
    if status:
        final = status[-1]["stamp_us"]
        flush = [e for e in status[-1]["events"] if e["time_us"] == final]
        for e in flush:
            print(f"NOTE not counted: {e['event']} from the host's end-of-log flush "
                  f"({e['detail']})")
        events = [e for e in events if not any(e is f for f in flush)]
    stale_ev = [e["time_us"] for e in events if e["event"] == "kinematics_stale"]
    check("one kinematics_stale event, 0.25-1 s after the stop",
          len(stale_ev) == 1 and a.stop + 250_000 <= stale_ev[0] <= a.stop + 1_000_000,
          f"at {[round((t - a.stop) * us, 3) for t in stale_ev]} s after the stop")
    fresh_ev = [e["time_us"] for e in events if e["event"] == "kinematics_fresh"]
    if a.hold:
        check("one kinematics_fresh event, within 0.5 s of the restart",
              len(fresh_ev) == 1 and restart <= fresh_ev[0] <= restart + 500_000,
              f"at {[round((t - restart) * us, 3) for t in fresh_ev]} s after the restart")
    else:
        check("no kinematics_fresh event", not fresh_ev)
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
