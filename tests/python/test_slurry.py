"""The Python module `slurry` (python/slurry_module.cpp): scenes from dicts and files with the
file's validation and messages, simulations stepped from Python, particle arrays that read the
solver's memory, runs with a callback per frame. Run by ctest (python.pytest) with the built
module on PYTHONPATH."""
import json
import math
import os

import numpy as np
import pytest

import slurry

EXAMPLES = os.environ.get("SLURRY_EXAMPLES_DIR", "")

# A jelly block falling freely in 2D (no wall within reach for 0.2 s).
FALL = {
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.4, 0.6], "max": [0.6, 0.8], "material": "jelly"}],
    "output": {"directory": "frames", "fps": 24, "frames": 4},
}


def test_free_fall_matches_the_analytic_drop():
    sim = slurry.make_simulation(slurry.parse_scene(FALL))
    y0 = float(np.mean(sim.positions[:, 1]))
    steps = sim.advance_to(0.2)
    assert steps > 0 and sim.steps == steps
    assert sim.time == pytest.approx(0.2)
    drop = y0 - float(np.mean(sim.positions[:, 1]))
    # The centre of mass falls g t^2 / 2 = 0.1962 m; symplectic Euler's lag is one step of g dt t.
    assert drop == pytest.approx(0.5 * 9.81 * 0.2**2, rel=0.02)
    vy = float(np.mean(sim.velocities[:, 1]))
    assert vy == pytest.approx(-9.81 * 0.2, rel=0.01)
    stats = sim.stats()
    assert stats["mass"] == pytest.approx(1000 * 0.2 * 0.2, rel=1e-6)
    assert stats["momentum"][1] == pytest.approx(stats["mass"] * vy, rel=1e-4)


def test_particle_arrays_are_the_solvers_memory_read_only():
    sim = slurry.make_simulation(slurry.parse_scene(FALL))
    x = sim.positions
    assert x.shape == (sim.particle_count, 2) and x.dtype == np.float32
    assert not x.flags.writeable
    # No copy: two reads are the same memory, and the frame's copy holds the same values.
    assert sim.positions.__array_interface__["data"][0] == x.__array_interface__["data"][0]
    frame = sim.frame(["position"])
    order = sim.id_order()
    assert np.array_equal(frame["vertex"]["x"], x[order, 0].astype(np.float64))
    with pytest.raises(ValueError):
        x[0, 0] = 1
    # The array keeps the simulation alive.
    del sim
    assert np.isfinite(x).all()
    # F of a solid: (n, 2, 2), the identity at rest; no J for a solid.
    sim = slurry.make_simulation(slurry.parse_scene(FALL))
    F = sim.F
    assert F.shape == (sim.particle_count, 2, 2)
    assert np.allclose(F, np.eye(2))
    assert sim.J is None


def test_ids_in_storage_order_and_the_id_permutation():
    scene = dict(FALL, solver={"type": "flip", "dimension": 2, "transfer": "apic"},
                 materials=[{"name": "water", "model": "fluid"}],
                 bodies=[{"shape": "box", "min": [0.1, 0.1], "max": [0.5, 0.5], "material": "water"}],
                 output={"directory": "frames", "fps": 24, "frames": 4, "attributes": ["position", "id"]})
    sim = slurry.make_simulation(slurry.parse_scene(scene))
    sim.advance_to(0.1)  # FLIP sorts its particles by cell
    ids = np.array(sim.ids)
    order = sim.id_order()
    assert np.array_equal(np.sort(ids), np.arange(sim.particle_count))
    assert np.array_equal(ids[order], np.arange(sim.particle_count))


def test_errors_name_the_key_and_the_file(tmp_path):
    bad = json.loads(json.dumps(FALL))
    bad["domain"]["dx"] = -1
    with pytest.raises(slurry.SceneError) as e:
        slurry.parse_scene(bad, "mine.json")
    assert "mine.json" in str(e.value) and "domain.dx" in str(e.value)
    assert isinstance(e.value, ValueError)
    with pytest.raises(slurry.IoError) as e:
        slurry.load_scene(str(tmp_path / "missing.json"))
    assert "missing.json" in str(e.value) and isinstance(e.value, OSError)
    with pytest.raises(TypeError):
        slurry.parse_scene(42)


def test_run_with_a_callback_per_frame(tmp_path):
    seen = []
    summary = slurry.run_scene(slurry.parse_scene(FALL), directory=str(tmp_path / "out"), threads=1,
                               on_frame=lambda f: seen.append((f["frame"], f["stats"]["time"], f["file"])))
    assert [s[0] for s in seen] == [0, 1, 2, 3, 4]
    assert seen[4][1] == pytest.approx(4 / 24)
    assert all(os.path.exists(s[2]) for s in seen)
    assert summary["frames_written"] == 5
    # A callback that raises stops the run after its frame and the error reaches the caller.
    def stop_at_2(f):
        if f["frame"] == 2:
            raise RuntimeError("enough")
    with pytest.raises(RuntimeError, match="enough"):
        slurry.run_scene(slurry.parse_scene(FALL), directory=str(tmp_path / "out2"), threads=1, on_frame=stop_at_2)
    assert not os.path.exists(tmp_path / "out2" / "frame_0004.ply")


@pytest.mark.skipif(not EXAMPLES, reason="SLURRY_EXAMPLES_DIR not set")
def test_a_shipped_scene_file_loads_and_steps():
    scene = slurry.load_scene(os.path.join(EXAMPLES, "snowball_2d.json"))
    sim = slurry.make_simulation(scene)
    sim.advance_to(scene.frame_dt)
    assert sim.particle_count > 0 and np.isfinite(sim.positions).all()
