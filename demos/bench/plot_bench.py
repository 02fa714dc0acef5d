#!/usr/bin/python3
"""Draws sinew-bench's work-precision plot: wall time per simulated second against the RMS node error
at t = 1 s and at t = 2 s, each system against its own converged reference (reads DIR/work_precision.csv,
writes DIR/work_precision.png). Usage: plot_bench.py DIR"""
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)

STYLE = {
    "sinew": ("tab:red", "o"),
    "sinew-implicit": ("tab:orange", "s"),
    "sinew-implicit-bending": ("tab:brown", "P"),
    "sinew-multigrid": ("tab:purple", "D"),
    "bullet-classic": ("tab:blue", "^"),
    "bullet-deformable": ("tab:green", "v"),
}


def main(folder):
    rows = list(csv.DictReader(open(f"{folder}/work_precision.csv")))
    series = {}
    for r in rows:
        ms, err1, err2 = float(r["ms_per_sim_s"]), float(r["rms_t1"]), float(r["rms_t2"])
        if r["survived"] != "1" or not all(map(math.isfinite, (ms, err1, err2))) or min(err1, err2) <= 0:
            continue
        series.setdefault((r["system"], int(r["n"])), []).append((err1, err2, ms, r["ticks"]))
    sizes = sorted({n for _, n in series})
    dashes = ["-", "--", ":", "-."]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharey=True)
    for ax, column, title in ((axes[0], 0, "RMS node error at t = 1 s"), (axes[1], 1, "RMS node error at t = 2 s")):
        for (system, n), points in sorted(series.items()):
            points.sort(key=lambda p: p[column])
            color, marker = STYLE.get(system, ("black", "x"))
            ax.plot([p[column] for p in points], [p[2] for p in points], marker=marker, color=color,
                    linestyle=dashes[sizes.index(n) % len(dashes)], label=f"{system} {n}x{n}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{title} vs own converged reference [m]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("wall time per simulated second [ms]")
    axes[1].legend(fontsize=8, loc="best")
    fig.suptitle("Benchmark curtain: speed against error (lower left is better)")
    fig.tight_layout()
    fig.savefig(f"{folder}/work_precision.png", dpi=110)
    print(f"plot: {folder}/work_precision.png")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
