#!/usr/bin/python3
"""Plots `skinbus-bench cpu --csv` output: batch-1 and batched time per kernel set and precision,
with each set's float32 floor and LibTorch at its best.

    tools/plot_cpu.py cpu.csv cpu.png
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1], newline="") as f:
        rows = list(csv.DictReader(f))
    rows = [r for r in rows if r["isa"] != "portable"] + [r for r in rows if r["isa"] == "portable"]
    labels = [f'{r["isa"]}\n{r["precision"]}' for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, key, title in (
        (axes[0], "batch1_us", "batch 1, one thread"),
        (axes[1], "batch64_1t_us", "batch 64, one thread (per sample)"),
    ):
        values = [float(r[key]) for r in rows]
        colours = ["tab:gray" if r["isa"] == "libtorch" else
                   "tab:orange" if r["precision"] == "int8" else "tab:blue" for r in rows]
        ax.bar(range(len(rows)), values, color=colours)
        for i, r in enumerate(rows):
            floor = float(r["floor_us"])
            if key == "batch1_us" and floor > 0:
                ax.plot([i - 0.4, i + 0.4], [floor, floor], "k--", lw=1)
            ax.text(i, values[i], f"{values[i]:.0f}", ha="center", va="bottom", fontsize=8)
        ax.set_yscale("log")
        ax.set_xticks(range(len(rows)))
        ax.set_xticklabels(labels, fontsize=8)
        ax.set_ylabel("µs per sample")
        ax.set_title(title)
    axes[0].plot([], [], "k--", lw=1, label="float32 floor (2 x MACs / FMA peak)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Seed CNN on the host runtime: blue float32, orange int8, grey LibTorch")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
