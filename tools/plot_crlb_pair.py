#!/usr/bin/python3
"""Plot the two-contact Cramer-Rao bound written by `skinbus-crlb --pair --csv`: per depth, the
mean XY bound of a contact against the separation of the pair (solid) and of the same contacts
pressed alone (dashed), and their ratio.

    tools/plot_crlb_pair.py pair.csv pair.png   (Debian's python3 with python3-matplotlib)
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    pair, alone = defaultdict(list), defaultdict(list)
    for r in rows:
        if r["identifiable"] != "1":
            continue
        key = (float(r["depth_mm"]), float(r["separation_mm"]))
        pair[key] += [float(r["sd_xy_first_mm"]), float(r["sd_xy_second_mm"])]
        alone[key] += [float(r["alone_xy_first_mm"]), float(r["alone_xy_second_mm"])]
    if not pair:
        sys.exit("plot_crlb_pair.py: no identifiable pair in " + sys.argv[1])
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    fig, (ax, ratio) = plt.subplots(1, 2, figsize=(10, 4))
    for depth in sorted({d for d, _ in pair}):
        seps = sorted(s for d, s in pair if d == depth)
        p = [mean(pair[(depth, s)]) for s in seps]
        a = [mean(alone[(depth, s)]) for s in seps]
        line, = ax.plot(seps, p, marker="o", label=f"{depth:g} mm deep")
        ax.plot(seps, a, linestyle="--", color=line.get_color())
        ratio.plot(seps, [x / y for x, y in zip(p, a)], marker="o", color=line.get_color(),
                   label=f"{depth:g} mm deep")
    ax.set_yscale("log")
    ax.set_xlabel("separation of the two contacts (mm)")
    ax.set_ylabel("XY bound per contact (mm, RMS)")
    ax.set_title("two contacts (solid) and each alone (dashed)")
    ratio.set_yscale("log")
    ratio.axhline(1, color="grey", linewidth=0.8)
    ratio.set_xlabel("separation of the two contacts (mm)")
    ratio.set_ylabel("bound with the other press / alone")
    ratio.set_title("what the second press costs")
    for a in (ax, ratio):
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=100)
    print(f"plot_crlb_pair.py: wrote {sys.argv[2]}")


if __name__ == "__main__":
    main()
