#!/usr/bin/python3
"""Plot the touch residuals written by `skinbus-calibrate --residuals` (or --plot): per patch,
each touch's residual after calibration (outliers in red), and the inliers' residuals in noise
units against the distribution they should follow if the noise is as stated (chi, 3 degrees of
freedom).

    tools/plot_calibration.py residuals.csv residuals.png [outlier_sigma]
"""
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    limit = float(sys.argv[3]) if len(sys.argv) == 4 else None
    with open(sys.argv[1]) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit("plot_calibration.py: no residuals in " + sys.argv[1])
    nodes = sorted({int(r["node"]) for r in rows})
    index = {n: i for i, n in enumerate(nodes)}
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [3, 2]})
    rng = np.random.default_rng(0)
    for outlier, colour, label in ((False, "tab:blue", "inlier"), (True, "tab:red", "outlier")):
        sel = [r for r in rows if (r["outlier"] == "1") == outlier]
        if not sel:
            continue
        x = [index[int(r["node"])] + rng.uniform(-0.25, 0.25) for r in sel]
        a.scatter(x, [float(r["residual_mm"]) for r in sel], s=10, c=colour, label=label)
    a.set_yscale("log")
    a.set_xticks(range(len(nodes)), [str(n) for n in nodes])
    a.set_xlabel("patch (node)")
    a.set_ylabel("residual after calibration, mm")
    a.set_title("residual of every touch")
    a.legend()
    a.grid(True, which="both", alpha=0.3)
    inl = np.array([float(r["residual_sigma"]) for r in rows if r["outlier"] == "0"])
    b.hist(inl, bins=30, density=True, alpha=0.6, label="inliers")
    x = np.linspace(0, max(5.0, inl.max() if inl.size else 5.0), 200)
    b.plot(x, np.sqrt(2 / math.pi) * x**2 * np.exp(-x**2 / 2), "k-", label="expected (chi, 3 dof)")
    if limit:
        b.axvline(limit, color="tab:red", ls="--", label="outlier limit")
    b.set_xlabel("residual / noise (whitened)")
    b.set_title("are the residuals the stated noise?")
    b.legend()
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
