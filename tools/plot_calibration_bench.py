#!/usr/bin/python3
"""Plot `skinbus-bench calibration --csv`: pose error (mean and p95) and solve time per patch
against the number of touches, one line per probe noise level, with the goals marked.

    tools/plot_calibration_bench.py calibration.csv calibration.png
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        rows = list(csv.DictReader(f))
    noises = sorted({float(r["probe_noise_mm"]) for r in rows})
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    panels = [("pos", "position error, mm", 0.5), ("rot", "rotation error, degrees", 0.3)]
    for ax, (key, label, goal) in zip(axes, panels):
        for noise in noises:
            sel = sorted((int(r["touches"]), r) for r in rows if float(r["probe_noise_mm"]) == noise)
            x = [t for t, _ in sel]
            line, = ax.plot(x, [float(r[key + "_mean_" + ("mm" if key == "pos" else "deg")])
                                for _, r in sel], "o-", label=f"probe noise {noise:g} mm (mean)")
            ax.plot(x, [float(r[key + "_p95_" + ("mm" if key == "pos" else "deg")]) for _, r in sel],
                    "--", color=line.get_color(), alpha=0.6, label=f"{noise:g} mm (p95)")
        ax.axhline(goal, color="k", lw=0.8, ls=":", label="goal at 30 touches, 0.5 mm")
        ax.axvline(30, color="k", lw=0.5, alpha=0.3)
        ax.set_xlabel("touches per patch")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    ax = axes[2]
    for noise in noises:
        sel = sorted((int(r["touches"]), r) for r in rows if float(r["probe_noise_mm"]) == noise)
        ax.plot([t for t, _ in sel], [float(r["solve_median_ms"]) for _, r in sel], "o-",
                label=f"{noise:g} mm")
    ax.set_xlabel("touches per patch")
    ax.set_ylabel("solve time per patch, ms (median)")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.suptitle("patch pose calibration (10% outlier touches)")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
