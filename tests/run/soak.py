#!/usr/bin/env python3
"""Soak test of the run loop: crash, resume, and memory over a long run.

A 2D MPM scene (snow and jelly, two materials, a collider) is run for FRAMES frames with a
checkpoint every 10 frames, twice:

  1. uninterrupted, with `slurry run`, sampling the process's resident memory every few
     milliseconds (from its page tables, /proc/PID/smaps_rollup) over frames 100-200 (or the
     fifth and tenth of the run) and over the run's last 100 frames;
  2. killed with SIGKILL at random moments, at least KILLS times, each time continued with
     `slurry resume` (or `slurry run` again if no checkpoint was written yet).

It passes when every frame and stats.csv of run 2 are byte-identical to run 1's, each kill hit a
running process, and the largest memory sampled at the end is within 5% of that around frame 200
(flat: a leak of a few bytes per frame or per substep shows over thousands of frames). Exit 0 on
pass, 1 on a failed check; the figures are printed.

  python3 tests/run/soak.py --slurry build/release/bin/slurry --frames 2000 --kills 20
"""
import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time

SCENE = {
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.025},
    "solver": {"dimension": 2, "transfer": "mls", "kernel": "quadratic", "max_dt": 0.004},
    "materials": [
        {"name": "snow", "model": "fixed_corotated", "density": 400, "E": 1e4, "nu": 0.2,
         "plasticity": "snow", "hardening": 5},
        {"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [
        {"shape": "sphere", "center": [0.3, 0.5], "radius": 0.15, "material": "snow",
         "velocity": [4, 1], "particles_per_cell": 4, "sampling": "jittered", "seed": 7},
        {"shape": "box", "min": [0.55, 0.1], "max": [0.8, 0.35], "material": "jelly",
         "particles_per_cell": 4}],
    "colliders": [{"shape": "box", "min": [0.85, 0.0], "max": [0.95, 0.9], "friction": 0.5}],
    "boundaries": {"friction": 0.3},
    "output": {"directory": "frames", "fps": 24, "frames": 2000, "checkpoint_every": 10,
               "attributes": ["position", "velocity", "J", "plastic", "material"]},
}


def rss_kib(pid):
    """The process's resident memory (KiB) counted from its page tables (smaps_rollup), or None
    once it has gone. (VmHWM and VmRSS in /proc/PID/status lag by up to 64 pages per thread: the
    kernel caches its counters per thread.)"""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Rss:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def frame_path(directory, f):
    return os.path.join(directory, "frame_%04d.ply" % f)


def reference_run(slurry, scene, out, frames, probe_frame):
    """Runs the scene uninterrupted; returns (seconds, the largest resident memory (KiB) sampled
    over frames probe_frame / 2 to probe_frame, the same over the last probe_frame / 2 frames)."""
    start = time.monotonic()
    p = subprocess.Popen([slurry, "run", scene, "--out", out, "--threads", "1", "--quiet"],
                         stdout=subprocess.DEVNULL)
    early = late = None
    written = 0  # frames written so far
    while p.poll() is None:
        while os.path.exists(frame_path(out, written + 1)):
            written += 1
        rss = rss_kib(p.pid)
        if rss is not None and probe_frame // 2 <= written < probe_frame:
            early = max(early or 0, rss)
        if rss is not None and written >= frames - probe_frame // 2 and written < frames:
            late = max(late or 0, rss)
        time.sleep(0.002)
    seconds = time.monotonic() - start
    if p.returncode != 0:
        sys.exit(f"soak: the uninterrupted run failed with exit code {p.returncode}")
    return seconds, early, late


def killed_run(slurry, scene, out, frames, kills, seconds, rng):
    """Runs the scene killed with SIGKILL `kills` times, resuming each time; returns (kills that hit
    a running process, runs started). The kills fall at random frames spread over the run, each at
    a random moment up to two frames' time after that frame's file appeared: inside a substep,
    while a frame or a checkpoint is being written, between files."""
    hits = runs = 0
    frame_seconds = seconds / frames
    targets = sorted(rng.sample(range(1, frames - 1), kills))
    for target in targets + [None]:
        has_checkpoint = os.path.isdir(out) and any(n.endswith(".slc") for n in os.listdir(out))
        written = [int(n[6:-4]) for n in os.listdir(out) if n.startswith("frame_") and n.endswith(".ply")] \
            if os.path.isdir(out) else []
        cmd = ([slurry, "resume", out] if has_checkpoint else [slurry, "run", scene, "--out", out])
        p = subprocess.Popen(cmd + ["--threads", "1", "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        runs += 1
        if target is not None:
            # A frame file this process writes itself: none beyond those the last one left.
            wait_for = frame_path(out, max([target] + [w + 1 for w in written]))
            while p.poll() is None and not os.path.exists(wait_for):
                time.sleep(0.002)
            time.sleep(rng.uniform(0, 2 * frame_seconds))
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
                hits += 1
            p.wait()
            err = p.stderr.read().decode(errors="replace")
            p.stderr.close()
            if p.returncode not in (0, -signal.SIGKILL):
                sys.exit(f"soak: {' '.join(cmd)} failed with exit code {p.returncode}:\n{err}")
            continue
        err = p.communicate()[1].decode(errors="replace")
        if p.returncode != 0:
            sys.exit(f"soak: {' '.join(cmd)} failed with exit code {p.returncode}:\n{err}")
    return hits, runs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--slurry", required=True, help="the slurry executable")
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", action="store_true", help="keep the working directory")
    args = ap.parse_args()
    if args.frames < 20 or args.kills < 1:
        sys.exit("soak: expected --frames >= 20 and --kills >= 1")
    work = tempfile.mkdtemp(prefix="slurry_soak_")
    scene = os.path.join(work, "scene.json")
    SCENE["output"]["frames"] = args.frames
    with open(scene, "w") as f:
        json.dump(SCENE, f, indent=2)
    ref, soak = os.path.join(work, "ref"), os.path.join(work, "soak")
    probe = min(200, args.frames // 10)
    seconds, at_probe, at_end = reference_run(args.slurry, scene, ref, args.frames, probe)
    hits, runs = killed_run(args.slurry, scene, soak, args.frames, args.kills, seconds,
                            random.Random(args.seed))
    failures = []
    names = ["stats.csv"] + ["frame_%04d.ply" % f for f in range(args.frames + 1)]
    differ = []
    for name in names:
        a, b = os.path.join(ref, name), os.path.join(soak, name)
        if not os.path.exists(b):
            differ.append(name + " (missing)")
            continue
        with open(a, "rb") as fa, open(b, "rb") as fb:
            if fa.read() != fb.read():
                differ.append(name)
    leftovers = [n for n in os.listdir(soak) if ".tmp-" in n]
    print(f"soak: {args.frames} frames, uninterrupted in {seconds:.1f} s; {hits} SIGKILLs over {runs} runs")
    print(f"soak: {len(names) - len(differ)} of {len(names)} files byte-identical to the uninterrupted run"
          + (f"; differ: {', '.join(differ[:10])}" if differ else ""))
    if differ:
        failures.append(f"{len(differ)} files differ")
    if leftovers:
        failures.append(f"temporary files left: {', '.join(leftovers[:5])}")
    if hits < args.kills:
        failures.append(f"only {hits} of {args.kills} kills hit a running process")
    if at_probe is None or at_end is None:
        failures.append("the resident memory was not sampled (is /proc/PID/smaps_rollup readable?)")
    else:
        growth = (at_end - at_probe) / at_probe
        print(f"soak: largest resident memory {at_probe} KiB over frames {probe // 2}-{probe}, {at_end} KiB "
              f"over frames {args.frames - probe // 2}-{args.frames} ({100 * growth:+.2f}%)")
        if growth > 0.05:
            failures.append(f"memory grew {100 * growth:.1f}% from frame {probe} to frame {args.frames} (limit 5%)")
    if failures:
        print("soak: FAILED: " + "; ".join(failures) + f" (kept {work})")
        return 1
    if not args.keep:
        shutil.rmtree(work)
    print("soak: passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
