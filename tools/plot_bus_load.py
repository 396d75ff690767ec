#!/usr/bin/python3
"""Plot of a recording's bus load over time, from `skinbus-budget --log LOG --csv CSV`.

  plot_bus_load.py LOG OUT.png [BUILD_DIR]   (runs skinbus-budget from BUILD_DIR, default build)
"""
import csv
import os
import subprocess
import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    log, png = sys.argv[1], sys.argv[2]
    build = sys.argv[3] if len(sys.argv) == 4 else os.path.join(os.path.dirname(__file__), "..", "build")
    with tempfile.NamedTemporaryFile(suffix=".csv") as tmp:
        summary = subprocess.run([os.path.join(build, "tools", "skinbus-budget"), "--log", log,
                                  "--interval-ms", "100", "--csv", tmp.name],
                                 check=True, capture_output=True, text=True).stdout
        with open(tmp.name, newline="") as f:
            rows = list(csv.DictReader(f))
    if not rows:
        sys.exit("plot_bus_load.py: the log has no frames")
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for iface in sorted({r["interface"] for r in rows}):
        pts = [(float(r["t_s"]), 100 * float(r["load"])) for r in rows if r["interface"] == iface]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], label=iface)
    ax.set_xlabel("time from the first frame (s)")
    ax.set_ylabel("bus load, % (100 ms bins, worst-case stuffing)")
    ax.set_ylim(bottom=0)
    ax.legend()
    ax.set_title("bus load: " + summary.strip().splitlines()[0])
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    print(f"plot_bus_load.py: wrote {png}")


if __name__ == "__main__":
    main()
