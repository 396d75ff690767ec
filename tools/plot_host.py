#!/usr/bin/python3
"""Plot of `skinbus-bench host`: latency (p50, p99) and CPU use per configuration.

  plot_host.py OUT.png TABLE.csv [TABLE.csv ...]   (one CSV per mode, e.g. stream and event)
"""
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    rows = []
    for path in sys.argv[2:]:
        with open(path, newline="") as f:
            rows += list(csv.DictReader(f))
    if not rows:
        sys.exit("plot_host.py: empty tables")
    fig, (ax_lat, ax_cpu) = plt.subplots(1, 2, figsize=(13, 6))
    labels = [f"{r['mode']} {r['patches']} patches, {r['touched']} touched" for r in rows]
    x = range(len(rows))
    p50 = [float(r["p50_us"]) / 1000 for r in rows]
    p99 = [float(r["p99_us"]) / 1000 for r in rows]
    ax_lat.bar([i - 0.2 for i in x], [0 if math.isnan(v) else v for v in p50], 0.4, label="p50")
    ax_lat.bar([i + 0.2 for i in x], [0 if math.isnan(v) else v for v in p99], 0.4, label="p99")
    ax_lat.axhline(2.0, color="k", lw=0.8, ls="--", label="goal: p99 <= 2 ms (64 patches)")
    ax_lat.set_yscale("log")
    ax_lat.set_ylabel("frame arrival -> contacts ready (ms)")
    ax_lat.set_xticks(list(x), labels, fontsize=7, rotation=90)
    ax_lat.legend(fontsize=8)
    ax_lat.set_title("latency (no bar: no touched patch)")
    ax_cpu.bar(list(x), [float(r["cpu_percent"]) for r in rows], 0.6, color="tab:green")
    ax_cpu.set_ylabel("CPU (% of one core)")
    ax_cpu.set_xticks(list(x), labels, fontsize=7, rotation=90)
    ax_cpu.set_title("CPU use while paced at 41.7 Hz")
    fig.suptitle("skinbus-bench host")
    fig.tight_layout()
    fig.savefig(sys.argv[1], dpi=110)
    print(f"plot_host.py: wrote {sys.argv[1]}")


if __name__ == "__main__":
    main()
