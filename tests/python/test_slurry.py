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


def test_run_reports_its_own_error_estimate(tmp_path):
    scene = dict(FALL, output=dict(FALL["output"], error_estimate=True))
    seen = []
    slurry.run_scene(slurry.parse_scene(scene), directory=str(tmp_path / "out"), threads=1,
                     on_frame=lambda f: seen.append(f["stats"]))
    assert len(seen) == 5
    for s in seen:
        assert s["error_energy"] >= 0 and s["error_centroid"] >= 0
    # The block falls freely: the two resolutions' centroids agree to within a small part of dx,
    # and the stats rows carry the same columns.
    assert max(s["error_centroid"] for s in seen) < 0.05 * 0.05
    header = open(tmp_path / "out" / "stats.csv").readline().strip().split(",")
    assert header[-2:] == ["error_energy", "error_centroid"]
    assert "error_energy" not in slurry.make_simulation(slurry.parse_scene(FALL)).stats()


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


def test_step_takes_one_substep_of_the_stable_length():
    sim = slurry.make_simulation(slurry.parse_scene(FALL))
    dt = sim.stable_dt
    assert 0 < dt < 1 / 24
    t = sim.step()
    assert sim.steps == 1 and t == sim.time == pytest.approx(dt, rel=1e-12)
    # Free fall: one substep of symplectic Euler gives every particle vy = -g dt.
    assert float(np.mean(sim.velocities[:, 1])) == pytest.approx(-9.81 * dt, rel=1e-4)
    t2 = sim.step(dt=1e-4)  # a given length below the stable one: one substep of exactly that
    assert sim.steps == 2 and t2 == pytest.approx(dt + 1e-4, rel=1e-12)
    with pytest.raises(ValueError, match="substep length"):
        sim.step(dt=-1.0)


def test_progress_callbacks_and_the_text_fallback(tmp_path, capfd):
    sim = slurry.make_simulation(slurry.parse_scene(FALL))
    seen = []
    sim.advance_to(0.2, progress=lambda done, total: seen.append((done, total)))
    assert len(seen) == math.ceil(0.2 * 24)  # once a frame
    assert all(total == pytest.approx(0.2) for _, total in seen)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen) and seen[-1][0] == pytest.approx(0.2)
    frames = []
    slurry.run_scene(slurry.parse_scene(FALL), directory=str(tmp_path / "p"), threads=1,
                     progress=lambda frame, total: frames.append((frame, total)))
    assert frames == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]
    with pytest.raises(TypeError, match="progress"):
        sim.advance_to(0.3, progress=42)
    try:
        import tqdm  # noqa: F401 (with tqdm installed, True draws its bar instead)
    except ImportError:
        slurry.run_scene(slurry.parse_scene(FALL), directory=str(tmp_path / "q"), threads=1, progress=True)
        assert "4 / 4 frame" in capfd.readouterr().err


def test_a_stop_token_from_another_thread_then_resume(tmp_path):
    import threading
    spec = dict(FALL, output=dict(FALL["output"], frames=6, checkpoint_every=2))
    scene = slurry.parse_scene(spec, "fall.json")
    whole = tmp_path / "whole"
    slurry.run_scene(scene, directory=str(whole), threads=1)
    token, reached, asked = slurry.StopToken(), threading.Event(), threading.Event()

    def on_frame(f):
        if f["frame"] == 3:  # wait here until the main thread has asked the run to stop
            reached.set()
            asked.wait(30)

    out = tmp_path / "stopped"
    result = {}
    worker = threading.Thread(target=lambda: result.update(
        slurry.run_scene(scene, directory=str(out), threads=1, on_frame=on_frame, stop=token)))
    worker.start()
    assert reached.wait(60)
    token.request()
    asked.set()
    worker.join(60)
    assert token.requested and result["stopped"] and result["frames_written"] == 4
    assert not (out / "frame_0004.ply").exists() and (out / "checkpoint_0003.slc").exists()
    # Resume continues from the checkpoint of the frame it stopped after, to the same last frame.
    resumed = slurry.run_scene(scene, directory=str(out), threads=1, resume=True)
    assert resumed["resumed_from"] == 3 and not resumed["stopped"]
    for f in range(7):
        name = f"frame_{f:04d}.ply"
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name


# A 3D FLIP ball of water (8 particles a cell), falling freely, asking for a PLY surface per frame.
BALL = {
    "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
    "solver": {"type": "flip", "dimension": 3, "transfer": "apic", "kernel": "linear"},
    "materials": [{"name": "water", "model": "fluid", "density": 1000}],
    "bodies": [{"shape": "sphere", "center": [0.5, 0.6, 0.5], "radius": 0.2, "material": "water",
                "particles_per_cell": 8}],
    "output": {"directory": "frames", "fps": 24, "frames": 2, "attributes": ["position", "velocity", "id"],
               "surface": ["ply"]},
}


def enclosed_volume(vertices, faces):
    a, b, c = (vertices[faces[:, k]].astype(np.float64) for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def test_the_surface_of_the_current_particles():
    sim = slurry.make_simulation(slurry.parse_scene(BALL))
    sim.advance_to(0.1)
    s = sim.surface()
    v, f, u = s["vertices"], s["faces"], s["velocities"]
    assert v.dtype == np.float32 and v.shape[1] == 3 and f.dtype == np.int32 and f.shape[1] == 3
    assert u.shape == v.shape and len(f) > 100 and f.min() >= 0 and f.max() < len(v)
    # The anisotropic surface keeps the particles' volume, count x spacing^3 (spacing dx / 2).
    particles_volume = sim.particle_count * (0.05 / 2) ** 3
    assert enclosed_volume(v, f) == pytest.approx(particles_volume, rel=0.03)
    # The ball falls as a whole at about g t: so do its surface's vertices.
    assert float(np.mean(u[:, 1])) == pytest.approx(float(np.mean(sim.velocities[:, 1])), rel=0.05)
    assert float(np.mean(u[:, 1])) == pytest.approx(-9.81 * 0.1, rel=0.05)
    spheres = sim.surface(method="spheres", smoothing=1)
    assert len(spheres["faces"]) > 0 and enclosed_volume(spheres["vertices"], spheres["faces"]) < enclosed_volume(v, f)
    with pytest.raises(ValueError, match="method"):
        sim.surface(method="blobs")
    with pytest.raises(slurry.SceneError, match="3D"):
        slurry.make_simulation(slurry.parse_scene(FALL)).surface()


def test_run_scene_writes_the_surfaces_the_scene_asks_for(tmp_path):
    files = []
    slurry.run_scene(slurry.parse_scene(BALL), directory=str(tmp_path), threads=1,
                     on_frame=lambda f: files.append(f["pipeline_files"]))
    assert [[os.path.basename(p) for p in fs] for fs in files] == [[f"surface_{k:04d}.ply"] for k in range(3)]
    with open(tmp_path / "surface_0002.ply", "rb") as fh:
        header = fh.read(400).decode("ascii", "replace")
    assert "property float vx" in header and "element face" in header


def test_surfacing_memory_is_kept_for_the_next_call_until_released(tmp_path):
    # On voxels of a tenth of a cell the surfacer's buffers reach its pool's 4 MiB threshold:
    # surface() keeps them for its next call; release_surfacing_memory returns them, once.
    sim = slurry.make_simulation(slurry.parse_scene(BALL))
    slurry.release_surfacing_memory()
    assert len(sim.surface(voxel_size=0.005)["faces"]) > 1000
    assert slurry.release_surfacing_memory() >= 4 << 20
    assert slurry.release_surfacing_memory() == 0
    # A run with the same surfaces returns them when it ends.
    scene = {**BALL, "output": {**BALL["output"], "frames": 1, "surface_voxel_size": 0.005}}
    files = []
    slurry.run_scene(slurry.parse_scene(scene), directory=str(tmp_path), threads=1,
                     on_frame=lambda f: files.append(f["pipeline_files"]))
    assert len(files) == 2 and all(len(fs) == 1 for fs in files)
    assert slurry.release_surfacing_memory() == 0
