#!/usr/bin/env python3
"""Error against CPU seconds (log-log), one PNG per problem, from tradeoff.csv.

usage: python3 plot.py RESULTS_DIR   (reads RESULTS_DIR/tradeoff.csv, writes RESULTS_DIR/<problem>.png)
Needs Debian's python3-matplotlib; only this script does.
"""
import csv
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

out = sys.argv[1] if len(sys.argv) > 1 else "."
rows = defaultdict(list)
with open(os.path.join(out, "tradeoff.csv")) as f:
    for r in csv.DictReader(f):
        if r["status"] != "ok" or r["error"] == "nan" or float(r["error"]) <= 0:
            continue
        rows[r["problem"]].append(r)

markers = {"default": ("k", "o"), "dx": ("k", "s"), "ppc": ("tab:blue", "^"), "kernel": ("tab:orange", "v"),
           "transfer": ("tab:green", "D"), "cfl": ("tab:red", "<"), "elastic_cfl": ("tab:purple", ">"),
           "max_dt": ("tab:brown", "p"), "integrator": ("tab:pink", "h"), "precision": ("tab:gray", "X"),
           "pressure.tolerance": ("tab:olive", "P"), "pressure.preconditioner": ("tab:cyan", "d"),
           "volume_correction": ("gold", "8"), "quality": ("crimson", "*")}

for problem, rs in rows.items():
    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    for knob, (color, marker) in markers.items():
        pts = [r for r in rs if r["knob"] == knob]
        if not pts:
            continue
        ax.scatter([float(r["cpu_s"]) for r in pts], [float(r["error"]) for r in pts], c=color, marker=marker,
                   s=90 if knob == "quality" else 40, label=knob, zorder=3, edgecolors="k" if knob == "quality" else None)
        if knob == "quality":
            for r in pts:
                ax.annotate(r["label"].split("=")[1], (float(r["cpu_s"]), float(r["error"])), fontsize=7,
                            xytext=(4, 4), textcoords="offset points")
    res = sorted([r for r in rs if r["knob"] in ("dx", "default")], key=lambda r: -float(r["dx"]))
    ax.plot([float(r["cpu_s"]) for r in res], [float(r["error"]) for r in res], "k--", lw=1, label="dx series")
    front = sorted([r for r in rs if r["pareto"] == "1"], key=lambda r: float(r["cpu_s"]))
    ax.step([float(r["cpu_s"]) for r in front], [float(r["error"]) for r in front], "g-", where="post", lw=1.5,
            alpha=0.6, label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("CPU seconds")
    ax.set_ylabel("error")
    ax.set_title(problem)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(os.path.join(out, problem + ".png"), dpi=90)
    plt.close(fig)
    print("wrote", os.path.join(out, problem + ".png"))
