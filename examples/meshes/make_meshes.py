#!/usr/bin/env python3
"""Writes the closed triangle meshes the mesh example scenes use (run from anywhere):

  icosphere.obj   unit sphere: an icosahedron subdivided three times (1280 triangles)
  column.obj      a cylinder of radius 1 and height 1 along y, base at y = 0, 48 sides, capped
  paddle.obj      a rounded paddle: a box 1 x 0.1 x 1 centred on the origin, its long edges
                  bevelled, the collider the examples spin through keyframes

Every mesh is closed and wound counter-clockwise seen from outside (Slurry checks both).
"""
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def write_obj(name, vertices, faces, comment):
    with open(os.path.join(HERE, name), "w") as f:
        f.write("# %s\n# written by make_meshes.py\n" % comment)
        for v in vertices:
            f.write("v %.9g %.9g %.9g\n" % v)
        for t in faces:
            f.write("f %s\n" % " ".join(str(i + 1) for i in t))


def icosphere(levels):
    g = (1 + 5 ** 0.5) / 2
    v = [(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g),
         (0, -1, -g), (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [tuple(c / math.sqrt(sum(x * x for x in p)) for c in p) for p in v]
    for _ in range(levels):
        mid = {}

        def midpoint(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = [(v[a][k] + v[b][k]) / 2 for k in range(3)]
                n = math.sqrt(sum(c * c for c in p))
                v.append(tuple(c / n for c in p))
                mid[key] = len(v) - 1
            return mid[key]

        nf = []
        for a, b, c in f:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return v, f


def cylinder(sides):
    v = [(0.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
    for k in range(sides):
        a = 2 * math.pi * k / sides
        v.append((math.cos(a), 0.0, -math.sin(a)))
        v.append((math.cos(a), 1.0, -math.sin(a)))
    f = []
    for k in range(sides):
        b0, t0 = 2 + 2 * k, 3 + 2 * k
        b1, t1 = 2 + 2 * ((k + 1) % sides), 3 + 2 * ((k + 1) % sides)
        f += [(b0, b1, t1), (b0, t1, t0), (0, b1, b0), (1, t0, t1)]
    return v, f


def paddle():
    # Cross-section in the x-y plane (an octagon: a 1 x 0.1 rectangle with bevelled corners),
    # extruded along z from -0.5 to 0.5.
    hx, hy, b = 0.5, 0.05, 0.03
    ring = [(hx, -hy + b), (hx, hy - b), (hx - b, hy), (-hx + b, hy), (-hx, hy - b), (-hx, -hy + b),
            (-hx + b, -hy), (hx - b, -hy)]
    n = len(ring)
    v = [(x, y, -0.5) for x, y in ring] + [(x, y, 0.5) for x, y in ring]
    f = []
    for k in range(n):
        a, c = k, (k + 1) % n
        f += [(a, c, n + c), (a, n + c, n + a)]
    for k in range(1, n - 1):
        f.append((0, k + 1, k))          # back cap (z = -0.5), facing -z
        f.append((n, n + k, n + k + 1))  # front cap (z = +0.5), facing +z
    return v, f


if __name__ == "__main__":
    write_obj("icosphere.obj", *icosphere(3), "unit icosphere, 1280 triangles")
    write_obj("column.obj", *cylinder(48), "cylinder r = 1, y in [0, 1], 48 sides")
    write_obj("paddle.obj", *paddle(), "bevelled paddle 1 x 0.1 x 1")
