#!/usr/bin/env python3
"""Largest and mean distance, in cells, between the particles of two PLY frames matched by their
`id` column: ply_distance.py A.ply B.ply DX MAX_CELLS. Exits 1 if the frames hold other sets of ids
or the largest distance exceeds MAX_CELLS (a FLIP run split over processes against one process,
tests/mpi/mpi_check.sh)."""
import sys

import numpy as np

TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
         "float": "f4", "double": "f8"}


def read(path):
    with open(path, "rb") as f:
        order, count, props, element = "<", 0, [], None
        while True:
            words = f.readline().decode("ascii").split()
            if not words:
                continue
            if words[0] == "format":
                if words[1] == "ascii":
                    sys.exit(f"{path}: ASCII PLY; expected binary")
                order = "<" if words[1] == "binary_little_endian" else ">"
            elif words[0] == "element":
                element = words[1]
                if element == "vertex":
                    count = int(words[2])
            elif words[0] == "property" and element == "vertex":
                props.append((words[2], order + TYPES[words[1]]))
            elif words[0] == "end_header":
                break
        dtype = np.dtype(props)
        return np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)


def main():
    a_path, b_path, dx, limit = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
    a, b = read(a_path), read(b_path)
    for path, v in ((a_path, a), (b_path, b)):
        if "id" not in v.dtype.names:
            sys.exit(f"{path}: no id column")
    a, b = a[np.argsort(a["id"])], b[np.argsort(b["id"])]
    if len(a) != len(b) or not np.array_equal(a["id"], b["id"]):
        print(f"{a_path} and {b_path}: other particles ({len(a)} and {len(b)})")
        sys.exit(1)
    axes = [c for c in ("x", "y", "z") if c in a.dtype.names]
    d = np.sqrt(sum((a[c].astype(float) - b[c].astype(float)) ** 2 for c in axes)) / dx
    print(f"{d.max():.3g} {d.mean():.3g}")
    sys.exit(0 if d.max() <= limit else 1)


if __name__ == "__main__":
    main()
