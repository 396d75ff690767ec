#!/usr/bin/python3
"""Plot a Cramer-Rao bound map written by `skinbus-crlb --csv`: one panel per depth, XY bound
and depth bound, with the sensor grid marked.

    tools/plot_crlb.py crlb.csv crlb.png   (Debian's python3 with python3-matplotlib)
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    rows = []
    meta = {}
    with open(sys.argv[1]) as f:
        lines = []
        for line in f:
            if line.startswith("#"):
                k, _, v = line[1:].partition(":")
                meta[k.strip()] = v.strip()
            else:
                lines.append(line)
        rows = list(csv.DictReader(lines))
    if not rows:
        sys.exit("plot_crlb.py: no rows in " + sys.argv[1])
    depths = sorted({float(r["depth_mm"]) for r in rows})
    fig, axes = plt.subplots(2, len(depths), figsize=(4.2 * len(depths), 7.4), squeeze=False)
    for col, depth in enumerate(depths):
        sel = [r for r in rows if float(r["depth_mm"]) == depth]
        us = sorted({float(r["u_mm"]) for r in sel})
        vs = sorted({float(r["v_mm"]) for r in sel})
        for row, key, label, vmax in ((0, "sd_xy_mm", "XY bound (mm)", None), (1, "sd_depth_mm", "depth bound (mm)", None)):
            grid = np.full((len(vs), len(us)), np.nan)
            for r in sel:
                if r["identifiable"] == "1":
                    grid[vs.index(float(r["v_mm"])), us.index(float(r["u_mm"]))] = float(r[key])
            ax = axes[row][col]
            im = ax.imshow(grid, origin="lower", extent=[us[0], us[-1], vs[0], vs[-1]], cmap="viridis",
                           vmin=0, vmax=np.nanpercentile(grid, 98) if vmax is None else vmax)
            for su in (-45, -15, 15, 45):
                for sv in (-45, -15, 15, 45):
                    ax.plot(su, sv, "w+", ms=6)
            ax.set_title(f"{label}, depth {depth:g} mm", fontsize=10)
            ax.set_xlabel("u (mm)")
            ax.set_ylabel("v (mm)")
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle("Cramer-Rao lower bound, nominal patch, noise %s / %s uT (xy / z); + = sensors"
                 % (meta.get("noise_xy_ut", "?"), meta.get("noise_z_ut", "?")), fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=90)


if __name__ == "__main__":
    main()
