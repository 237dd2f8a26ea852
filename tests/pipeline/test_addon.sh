#!/usr/bin/env bash
# The Blender add-on test (ctest label "pipeline"): the CLI runs the first frames of a shipped
# liquid scene with surfaces and colliders, then Blender installs the zipped add-on into a
# temporary user scripts folder and imports, steps and renders them (test_addon.py); with the
# Python module's folder, it also runs a small scene through the add-on's Run operator.
#   test_addon.sh SLURRY BLENDER ADDON_ZIP WORKDIR [MODULE_DIR]
set -euo pipefail
slurry=$1 blender=$2 addon=$3 work=$4 module=${5:-}
here=$(cd "$(dirname "$0")" && pwd)
scenes=$(cd "$here/../../examples/scenes" && pwd)
frames=3
rm -rf "$work"
mkdir -p "$work/user_scripts"
"$slurry" run "$scenes/mesh_dam_break_3d.json" --out "$work/frames" --frames $frames --quiet
run=()
[ -n "$module" ] && run=("$module" "$here/splash.json")
BLENDER_USER_SCRIPTS="$work/user_scripts" "$blender" -b --factory-startup --python-exit-code 1 \
  -P "$here/test_addon.py" -- "$addon" "$work/frames" $frames "$work/out" "${run[@]}"
