#!/usr/bin/env bash
# The Blender client test (ctest label "pipeline"): slurry writes a small scene's frames with
# every effects-pipeline output, then Blender imports them headless, checks the counts and
# renders a small Cycles CPU picture (blender_check.py).
#   blender_test.sh SLURRY BLENDER WORKDIR
set -euo pipefail
slurry=$1 blender=$2 work=$3
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$work"
mkdir -p "$work"
"$slurry" run "$here/splash.json" --out "$work/frames" --quiet
"$blender" -b --factory-startup --python-exit-code 1 -P "$here/blender_check.py" -- "$work/frames" 2 "$work/render.png" 160 120 8
