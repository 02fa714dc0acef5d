#!/usr/bin/python3
"""Draws sinew-bench's work-precision plot: wall time per simulated second against the RMS node error
at t = 1 s and at t = 2 s, each system against its own converged reference, one row per cloth
resolution; each system's line joins its front, the settings no other of its settings beats in both
(reads DIR/work_precision.csv, writes DIR/work_precision.png). Usage: plot_bench.py DIR"""
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
    # One row of panels per cloth resolution (errors at t = 1 s and 2 s side by side), so the systems'
    # curves at one resolution are read together.
    fig, grid = plt.subplots(len(sizes), 2, figsize=(13, 4.6 * len(sizes)), squeeze=False)
    for row, n in enumerate(sizes):
        for column, title in ((0, "RMS node error at t = 1 s"), (1, "RMS node error at t = 2 s")):
            ax = grid[row][column]
            for (system, size), points in sorted(series.items()):
                if size != n:
                    continue
                color, marker = STYLE.get(system, ("black", "x"))
                # Every setting as a marker; the line joins the system's front, the settings that no
                # other setting of the same system beats in both time and error.
                ax.scatter([p[column] for p in points], [p[2] for p in points], marker=marker, color=color, alpha=0.45, s=22)
                front = [p for p in points if not any(q[column] <= p[column] and q[2] <= p[2] and q != p for q in points)]
                front.sort(key=lambda p: p[column])
                ax.plot([p[column] for p in front], [p[2] for p in front], marker=marker, color=color, label=system)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(f"{n} x {n} cloth", fontsize=10)
            ax.set_xlabel(f"{title} vs own converged reference [m]")
            ax.set_ylabel("wall time per simulated second [ms]")
            ax.grid(True, which="both", alpha=0.3)
        grid[row][1].legend(fontsize=8, loc="best")
    fig.suptitle("Benchmark curtain: speed against error (lower left is better)")
    fig.tight_layout()
    fig.savefig(f"{folder}/work_precision.png", dpi=110)
    print(f"plot: {folder}/work_precision.png")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
