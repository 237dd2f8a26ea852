#!/bin/bash
# The whole speed-against-accuracy study: builds the program, runs every point (2 at a time,
# one thread each), writes benchmarks/tradeoff/results/{tradeoff.csv,tradeoff.md,*.png}.
# Usage (from the repository root): bash benchmarks/tradeoff/run.sh [BUILD_DIR]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build/release}
out=$root/benchmarks/tradeoff/results
[ -f "$build/CMakeCache.txt" ] || cmake --preset release -S "$root"
cmake --build "$build" --target tradeoff -j2
mkdir -p "$out"
OMP_WAIT_POLICY=passive "$build/bin/tradeoff" --jobs 2 --threads 1 --out "$out" | tee "$out/run.log"
{
  echo "command: bash benchmarks/tradeoff/run.sh; date: $(date -u '+%Y-%m-%d %H:%M UTC'); commit: $(git -C "$root" rev-parse --short HEAD)"
  echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), load average before the run's end: $(cut -d' ' -f1-3 /proc/loadavg)"
} > "$out/machine.txt"
# Debian's python3-matplotlib is for /usr/bin/python3 (a python3 earlier on PATH may lack it).
py=/usr/bin/python3
[ -x "$py" ] || py=python3
"$py" "$root/benchmarks/tradeoff/plot.py" "$out"
