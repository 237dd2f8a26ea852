#!/usr/bin/env python3
"""A jelly ball dropped on the floor, built as a dict in Python, stepped frame by frame with its
particles read as NumPy arrays, and the energies plotted from the run's statistics.

    PYTHONPATH=build/release/python python3 examples/python/drop.py [out.png]
"""
import sys

import numpy as np

import slurry

scene = slurry.parse_scene({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.02},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 5e4, "nu": 0.3}],
    "bodies": [{"shape": "sphere", "center": [0.5, 0.6], "radius": 0.15, "material": "jelly"}],
    "output": {"directory": "out/drop_py", "fps": 30, "frames": 45},
}, "drop.py")
sim = slurry.make_simulation(scene)
times, kinetic, potential, elastic, lowest = [], [], [], [], []
for f in range(scene.frames + 1):
    sim.advance_to(f * scene.frame_dt)
    stats = sim.stats()
    times.append(stats["time"])
    kinetic.append(stats["kinetic"])
    potential.append(stats["potential"])
    elastic.append(stats["elastic"])
    lowest.append(float(sim.positions[:, 1].min()))  # read in place, no copy
print(f"{sim.particle_count} particles, {sim.steps} substeps; lowest point {min(lowest):.3f} m; "
      f"energy {kinetic[0] + potential[0] + elastic[0]:.2f} -> {kinetic[-1] + potential[-1] + elastic[-1]:.2f} J")

if len(sys.argv) > 1:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3))
    for name, values in (("kinetic", kinetic), ("potential", potential), ("elastic", elastic)):
        ax.plot(times, np.array(values) - (potential[0] if name == "potential" else 0), label=name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("energy (J, potential from its start)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(sys.argv[1], dpi=100)
    print(f"wrote {sys.argv[1]}")
