#!/usr/bin/env python3
"""The README's whitewater picture: one frame of flip_dam_break_whitewater_3d seen from the front
(x right, y up), the liquid's particles in grey-blue and the secondary particles coloured by type
(spray white-blue, foam white, bubbles teal) on a dark background. Reads the PLY files with NumPy
alone (no Slurry module needed).

    slurry run examples/scenes/flip_dam_break_whitewater_3d.json
    /usr/bin/python3 examples/python/whitewater_figure.py out/flip_dam_break_whitewater_3d 24 docs/images/whitewater.png
"""
import os
import sys

import numpy as np
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
             "float": "<f4", "double": "<f8"}


def read_ply(path):
    """The vertex element of a binary little-endian (or ASCII) PLY file as a dict of arrays."""
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        count, props, fmt, in_vertex = 0, [], "", False
        for line in header:
            words = line.split()
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                in_vertex = words[1] == "vertex"
                if in_vertex:
                    count = int(words[2])
            elif words[0] == "property" and in_vertex:
                props.append((words[2], PLY_TYPES[words[1]]))
        if fmt == "ascii":
            data = np.loadtxt(f, max_rows=count, ndmin=2)
            return {name: data[:, i] for i, (name, _) in enumerate(props)}
        rows = np.frombuffer(f.read(count * np.dtype(props).itemsize), dtype=np.dtype(props), count=count)
        return {name: rows[name] for name, _ in props}


def main():
    directory, frame, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    liquid = read_ply(os.path.join(directory, f"frame_{frame:04d}.ply"))
    white = read_ply(os.path.join(directory, f"whitewater_{frame:04d}.ply"))
    fig, ax = plt.subplots(figsize=(4.8, 3.0), dpi=100)
    fig.patch.set_facecolor("#10161c")
    ax.set_facecolor("#10161c")
    ax.scatter(liquid["x"], liquid["y"], s=1.2, c="#3f7fc0", alpha=0.45, linewidths=0)
    colours = {0: "#cfe8ff", 1: "#ffffff", 2: "#4fd1c5"}
    names = {0: "spray", 1: "foam", 2: "bubbles"}
    for kind in (2, 1, 0):
        sel = white["type"] == kind
        ax.scatter(white["x"][sel], white["y"][sel], s=0.8, c=colours[kind], alpha=0.8, linewidths=0,
                   label=f"{names[kind]} ({int(sel.sum())})")
    ax.set_xlim(0, 1.6)
    ax.set_ylim(0, 1.0)
    ax.set_aspect("equal")
    ax.axis("off")
    legend = ax.legend(loc="upper left", fontsize=7, frameon=False, markerscale=6)
    for text in legend.get_texts():
        text.set_color("#e0e0e0")
    fig.subplots_adjust(0, 0, 1, 1)
    fig.savefig(out, facecolor=fig.get_facecolor())
    print(f"{out}: frame {frame}, {len(liquid['x'])} liquid particles, {len(white['x'])} whitewater")


if __name__ == "__main__":
    main()
