#!/usr/bin/python3
"""Plot the three-contact table written by `skinbus-bench triples --csv`: per depth, how often
three presses are counted three against the side of their triangle (left), and each contact's
mean XY error next to the three-contact Cramer-Rao bound (right).

    tools/plot_triples.py triples.csv triples.png   (Debian's python3 with python3-matplotlib)
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
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit(f"{sys.argv[1]}: no rows")
    by_depth = defaultdict(list)
    for r in rows:
        by_depth[float(r["depth_mm"])].append(r)
    fig, (rate, err) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (depth, rs) in enumerate(sorted(by_depth.items())):
        rs.sort(key=lambda r: float(r["side_mm"]))
        side = [float(r["side_mm"]) for r in rs]
        color = f"C{i}"
        rate.plot(side, [100 * float(r["count3_rate"]) for r in rs], "o-", color=color,
                  label=f"{depth:g} mm deep")
        counted = [r for r in rs if float(r["count3_rate"]) > 0]
        s3 = [float(r["side_mm"]) for r in counted]
        err.plot(s3, [float(r["xy_error_mm"]) for r in counted], "o-", color=color,
                 label=f"{depth:g} mm: error")
        err.plot(s3, [float(r["crlb_xy_mm"]) for r in counted], "--", color=color,
                 label=f"{depth:g} mm: bound")
    rate.set_xlabel("side of the presses' triangle (mm)")
    rate.set_ylabel("samples counted three (%)")
    rate.set_ylim(-3, 103)
    rate.grid(alpha=0.3)
    rate.legend()
    err.set_xlabel("side of the presses' triangle (mm)")
    err.set_ylabel("XY error per contact (mm)")
    err.set_yscale("log")
    err.grid(alpha=0.3, which="both")
    err.legend(fontsize=8, ncol=2)
    fig.suptitle("Three presses on one patch (fabricated unit, its own model)")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
