#!/usr/bin/python3
"""Plots of `skinbus-bench models`: run time against error (Pareto) and per-position error maps.

  plot_models.py TABLE.csv ERRORS.csv STEM   -> STEM_pareto.png, STEM_error_map.png
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    table, errors, stem = read(sys.argv[1]), read(sys.argv[2]), sys.argv[3]
    if not table or not errors:
        sys.exit("plot_models.py: empty table or error file")
    # Mean XY error of presses >= 1 mm deep, per estimator, from the per-sample errors.
    deep = {}
    for r in errors:
        if float(r["depth_mm"]) >= 1.0 and r["valid"] == "1":
            deep.setdefault(r["estimator"], []).append(float(r["xy_error_mm"]))
    deep_mean = {k: sum(v) / len(v) for k, v in deep.items()}
    crlb = [float(r["crlb_xy_mm"]) for r in errors
            if r["estimator"] == errors[0]["estimator"] and float(r["depth_mm"]) >= 1.0]
    crlb_mean = sum(crlb) / len(crlb) if crlb else None

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    for ax, column, title in ((axes[0], "batch1_us", "batch 1, 1 thread"),
                              (axes[1], "batch64_2t_us", "batch 64, 2 threads")):
        pts = [(float(r[column]), deep_mean.get(r["estimator"], float("nan")), r["estimator"])
               for r in table]
        pts = [p for p in pts if p[0] > 0 and p[1] == p[1]]
        # One colour per model, one marker per precision (and for float32 with direct
        # convolutions where the default is Winograd); only the default float32 rows are labelled.
        def family_of(name):
            for suffix in (" bfloat16", " int8", " direct"):
                name = name.replace(suffix, "")
            return name

        def marker_of(name):
            return ("s" if name.endswith(" bfloat16") else "^" if name.endswith(" int8")
                    else "D" if name.endswith(" direct") else "o")

        families = list(dict.fromkeys(family_of(n) for _, _, n in pts))
        for t, e, name in pts:
            family = family_of(name)
            marker = marker_of(name)
            ax.scatter(t, e, s=40, marker=marker, color="C%d" % (families.index(family) % 10))
            if marker == "o":
                ax.annotate(name, (t, e), textcoords="offset points", xytext=(5, 4), fontsize=8)
        for marker, label in (("o", "float32 / other"), ("D", "float32, direct convolutions"),
                              ("s", "bfloat16"), ("^", "int8")):
            ax.scatter([], [], marker=marker, color="0.4", label=label)
        front, best = [], float("inf")
        for t, e, _ in sorted(pts):
            if e < best:
                front.append((t, e))
                best = e
        if front:
            ax.step([p[0] for p in front], [p[1] for p in front], where="post", color="0.6",
                    lw=1, label="Pareto front")
        if crlb_mean:
            ax.axhline(crlb_mean, color="tab:red", ls="--", lw=1,
                       label="CRLB (RMS XY bound, mean)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per sample (µs, %s)" % title)
        ax.set_ylabel("XY mean error, presses >= 1 mm deep (mm)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
    fig.suptitle("Per-patch estimators: run time against error (same test split)")
    fig.tight_layout()
    fig.savefig(stem + "_pareto.png", dpi=110)

    # Error maps: XY error of each test press >= 1 mm deep at its position, per estimator, and
    # the CRLB at the same presses.
    names = list(dict.fromkeys(r["estimator"] for r in errors))
    panels = [("CRLB (RMS XY bound)", [(float(r["u_mm"]), float(r["v_mm"]), float(r["crlb_xy_mm"]))
                                       for r in errors if r["estimator"] == names[0]
                                       and float(r["depth_mm"]) >= 1.0])]
    for n in names:
        if n.endswith((" bfloat16", " int8", "(LibTorch)")):
            continue
        panels.append((n, [(float(r["u_mm"]), float(r["v_mm"]), float(r["xy_error_mm"]))
                           for r in errors if r["estimator"] == n and r["valid"] == "1"
                           and float(r["depth_mm"]) >= 1.0]))
    cols = min(4, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.9 * rows), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    for ax, (name, pts) in zip(axes.flat, panels):
        ax.set_visible(True)
        sc = ax.scatter([p[0] for p in pts], [p[1] for p in pts], c=[p[2] for p in pts], s=9,
                        cmap="viridis", vmin=0, vmax=3.0)
        mean = sum(p[2] for p in pts) / max(len(pts), 1)
        ax.set_title("%s\nmean %.2f mm" % (name, mean), fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("u (mm)")
        ax.set_ylabel("v (mm)")
        fig.colorbar(sc, ax=ax, label="XY error (mm)")
    fig.suptitle("XY error at each off-grid test press >= 1 mm deep (colour clipped at 3 mm)")
    fig.tight_layout()
    fig.savefig(stem + "_error_map.png", dpi=100)


if __name__ == "__main__":
    main()
