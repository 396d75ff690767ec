#!/usr/bin/env python3
"""Damages candump -L logs the way the red-team did (tests/redteam/redteam.sh).

  logtool.py merge OUT IN...        logs shifted to start together, merged in time order
  logtool.py reverse OUT IN         lines in reverse order (stamps run backwards)
  logtool.py jump OUT IN LINE S     every line from LINE on (1-based) stamped S seconds later
                                    (negative: earlier, a clock set back)
  logtool.py swap OUT IN NODE K     the K-th and (K+1)-th sample messages of NODE arrive in swapped
                                    order (the stamps stay in order; every frame kept)
  logtool.py shuffle OUT IN FRAC SEED
                                    FRAC of the sample messages swapped with the next of their node
                                    (as swap; prints how many pairs)
  logtool.py shuffle-lines OUT IN FRAC SEED
                                    FRAC of the lines swapped with the next line, stamps and all (a
                                    log whose lines are out of time order; prints how many)
"""
import random
import re
import sys

LINE = re.compile(r"\((\d+)\.(\d+)\) (\S+) (\S+)(.*)")


def load(path):
    out = []
    for text in open(path):
        m = LINE.match(text.rstrip("\n"))
        if not m:
            continue
        t = int(m.group(1)) * 1_000_000 + int(m.group(2).ljust(6, "0")[:6])
        out.append([t, m.group(3), m.group(4), m.group(5)])
    return out


def save(path, frames):
    with open(path, "w") as f:
        for t, iface, frame, tail in frames:
            f.write(f"({t // 1_000_000}.{t % 1_000_000:06d}) {iface} {frame}{tail}\n")


def can_id(frame):
    return int(frame.split("#", 1)[0], 16)


def samples_of(frames, node=None):
    """The frames of each sample message (class 3: ids 0x180 + node), grouped by node and sequence
    (a message's parts are adjacent in a log), in order: [node, seq, [frame indices]]."""
    groups, current = [], {}
    for i, (_, _, frame, _) in enumerate(frames):
        ident = can_id(frame)
        n = ident & 0x7F
        if ident >> 7 != 3 or (node is not None and n != node):
            continue
        data = frame.split("##", 1)[1][1:] if "##" in frame else frame.split("#", 1)[1]
        seq = data[2:4]
        g = current.get(n)
        if g is None or g[1] != seq:
            g = [n, seq, []]
            groups.append(g)
            current[n] = g
        g[2].append(i)
    return groups


def swap_groups(frames, a, b):
    """Exchanges the places of two messages' frames (the stamps stay where they were)."""
    ia, ib = a[2], b[2]
    if len(ia) != len(ib):
        return False
    moved = [list(frames[i]) for i in ia], [list(frames[i]) for i in ib]
    for k, i in enumerate(ia):
        frames[i][1:] = moved[1][k][1:]
    for k, i in enumerate(ib):
        frames[i][1:] = moved[0][k][1:]
    return True


def main():
    cmd, out = sys.argv[1], sys.argv[2]
    if cmd == "merge":
        merged, t0 = [], None
        for k, path in enumerate(sys.argv[3:]):
            frames = load(path)
            first = frames[0][0]
            t0 = first if t0 is None else t0
            merged += [[t - first + t0, k, i, f, tail] for t, i, f, tail in frames]
        merged.sort(key=lambda x: (x[0], x[1]))
        save(out, [[t, i, f, tail] for t, _, i, f, tail in merged])
    elif cmd == "reverse":
        save(out, list(reversed(load(sys.argv[3]))))
    elif cmd == "jump":
        frames, line, s = load(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
        for fr in frames[line - 1:]:
            fr[0] += int(s * 1e6)
        save(out, frames)
    elif cmd == "swap":
        frames = load(sys.argv[3])
        groups = samples_of(frames, int(sys.argv[4]))
        k = int(sys.argv[5])
        assert swap_groups(frames, groups[k], groups[k + 1]), "messages of different sizes"
        save(out, frames)
    elif cmd == "shuffle":
        frames = load(sys.argv[3])
        frac, rng = float(sys.argv[4]), random.Random(int(sys.argv[5]))
        by_node = {}
        for g in samples_of(frames):
            by_node.setdefault(g[0], []).append(g)
        swapped = 0
        for groups in by_node.values():
            k = 0
            while k + 1 < len(groups):
                if rng.random() < frac and swap_groups(frames, groups[k], groups[k + 1]):
                    swapped += 1
                    k += 2
                else:
                    k += 1
        save(out, frames)
        print(swapped)
    elif cmd == "shuffle-lines":
        frames = load(sys.argv[3])
        frac, rng = float(sys.argv[4]), random.Random(int(sys.argv[5]))
        k, swapped = 0, 0
        while k + 1 < len(frames):
            if rng.random() < frac:
                frames[k], frames[k + 1] = frames[k + 1], frames[k]
                swapped += 1
                k += 2
            else:
                k += 1
        save(out, frames)
        print(swapped)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
