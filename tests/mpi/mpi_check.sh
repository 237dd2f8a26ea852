#!/usr/bin/env bash
# A run split over processes against the same run in one process (ctest label "mpi"):
#   mpi_check.sh CLI SCENE FRAMES NP [NP ...]      frames of mpirun -np NP equal one process's; NP:GRID
#                                                  (e.g. 4:2x2) also requires that many processes per axis
#   mpi_check.sh CLI SCENE FRAMES resume NP1 NP2   a run split over NP1 processes, stopped at
#                                                  frame FRAMES/2 and resumed over NP2, equals one process
#   mpi_check.sh CLI SCENE FRAMES refused NP       mpirun -np NP is refused with exit 2 (one-process solvers)
#   mpi_check.sh CLI SCENE FRAMES per_rank NP      with output.per_rank each of NP processes writes its own
#                                                  part of each frame; slurry merge joins them into the
#                                                  one-process frames; a missing part is refused (exit 3)
#   mpi_check.sh CLI SCENE FRAMES per_rank_resume NP1 NP2
#                                                  with output.per_rank over NP1 processes, stopped at frame
#                                                  FRAMES/2: each process wrote its own checkpoint part (no
#                                                  whole checkpoint); resumed over NP2 (1 included) from the
#                                                  parts; the frames, merged, equal one process's
#   NEAR=CELLS mpi_check.sh ...                    (a FLIP liquid, whose split solves the pressure
#                                                  otherwise) instead of byte-identical frames: each
#                                                  particle, matched by id, within CELLS of its place
#                                                  in the one-process frame (tests/mpi/ply_distance.py,
#                                                  run by $PYTHON, else python3)
# Every frame must be byte-identical to the one-process run's (cmp); stats.csv's mass and momentum,
# summed in another order over the ranks, must agree to 1e-9 (mass: relative; momentum: of
# sqrt(2 M K), which bounds sum m |v|). The split is checked to have happened (the per-frame log
# names the ranks and their imbalance). Runs over loopback only; as root (CI), OpenMPI needs its
# allow-run-as-root variables, and containers lack cross-memory attach for its shared-memory
# transport.
set -euo pipefail
cli=$1 scene=$2 frames=$3
shift 3
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export OMPI_MCA_btl_vader_single_copy_mechanism=none OMPI_MCA_rmaps_base_oversubscribe=1
export OMPI_MCA_btl=self,vader OMPI_MCA_oob_tcp_if_include=lo
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
name=$(basename "$scene" .json)
fail() { echo "FAIL: $name: $*"; exit 1; }
split_run() {  # NP DIR ARGS...
  local np=$1 dir=$2
  shift 2
  mpirun -np "$np" --oversubscribe "$cli" run "$scene" --out "$dir" "$@" > "$dir.log" 2>&1 || { cat "$dir.log"; return 1; }
}

if [ "${1:-}" = refused ]; then
  np=$2
  set +e
  mpirun -np "$np" --oversubscribe "$cli" run "$scene" --out "$work/refused" --frames 1 > "$work/refused.log" 2>&1
  rc=$?
  set -e
  [ "$rc" -eq 2 ] || { cat "$work/refused.log"; fail "mpirun -np $np exited $rc, expected 2"; }
  grep -q "runs in one process only" "$work/refused.log" || { cat "$work/refused.log"; fail "no message naming the one-process solver"; }
  [ ! -e "$work/refused/frame_0000.ply" ] || fail "a refused run wrote a frame"
  echo "$name: mpirun -np $np refused (exit 2): $(grep -o 'solver.type[^(]*' "$work/refused.log" | head -1)"
  exit 0
fi

"$cli" run "$scene" --out "$work/one" --frames "$frames" --threads 1 --quiet > "$work/one.log" 2>&1 || { cat "$work/one.log"; fail "the one-process run failed"; }

compare() {  # DIR LABEL
  local dir=$1 label=$2 n=0
  if [ -n "${NEAR:-}" ]; then
    local dx worst=0 far
    dx=$(grep -o '"dx": *[0-9.e+-]*' "$scene" | head -1 | sed 's/.*: *//')
    for f in "$work"/one/frame_*.ply; do
      far=$("${PYTHON:-python3}" "$(dirname "$0")/ply_distance.py" "$f" "$dir/$(basename "$f")" "$dx" "$NEAR") ||
        fail "$label: $(basename "$f"): a particle more than $NEAR cells from the one-process run's (largest, mean: ${far:-none})"
      worst=$(awk -v a="$worst" -v b="${far%% *}" 'BEGIN { print (b > a ? b : a) }')
      n=$((n + 1))
    done
    [ "$n" -eq $((frames + 1)) ] || fail "$label: $n frames, expected $((frames + 1))"
    echo "$name: $label: $n frames, every particle within $worst cells of one process's (at most $NEAR)"
    return
  fi
  for f in "$work"/one/frame_*.ply; do
    cmp -s "$f" "$dir/$(basename "$f")" || fail "$label: $(basename "$f") differs from the one-process run's (or is missing)"
    n=$((n + 1))
  done
  [ "$n" -eq $((frames + 1)) ] || fail "$label: $n frames, expected $((frames + 1))"
  # frame,time,substeps,particles,mass,momentum_x,_y,_z,angular x3,kinetic,...
  local worst
  worst=$(awk -F, 'NR == FNR { if (FNR > 1) { m[$1] = $5; p[$1] = $6 " " $7 " " $8; k[$1] = $12 } next }
    FNR > 1 { split(p[$1], q, " "); scale = sqrt(2 * m[$1] * k[$1]) + 1e-300;
      dm = ($5 - m[$1]) / m[$1]; if (dm < 0) dm = -dm; if (dm > w) w = dm;
      for (d = 1; d <= 3; ++d) { dp = ($(5 + d) - q[d]) / scale; if (dp < 0) dp = -dp; if (dp > w) w = dp }
      rows++ }
    END { if (rows == 0) print "none"; else printf "%.3g\n", w }' "$work/one/stats.csv" "$dir/stats.csv")
  [ "$worst" != none ] || fail "$label: stats.csv has no rows"
  awk -v w="$worst" 'BEGIN { exit !(w <= 1e-9) }' || fail "$label: mass or momentum differs by $worst (expected <= 1e-9)"
  echo "$name: $label: $n frames byte-identical to one process; mass and momentum within $worst"
}

if [ "${1:-}" = resume ] || [ "${1:-}" = per_rank_resume ]; then
  mode=$1 np1=$2 np2=$3 half=$((frames / 2))
  # Checkpoints every frame (the scene's output block with checkpoint_every 1), in parts with
  # per_rank_resume.
  keys='"checkpoint_every": 1,'
  [ "$mode" = resume ] || keys='"per_rank": true, "checkpoint_every": 1,'
  # Compared by id when NEAR is set: the frames list the id.
  sed -e "s/\"output\": {/\"output\": { $keys/" -e "${NEAR:+s/\"attributes\": \[/\"attributes\": [\"id\", /}" "$scene" > "$work/$name.json"
  scene="$work/$name.json"
  mkdir -p "$work/resumed"
  split_run "$np1" "$work/resumed" --frames "$half" --quiet || fail "mpirun -np $np1 (first half) failed"
  checkpoint="$work/resumed/checkpoint_$(printf %04d "$half")"
  if [ "$mode" = resume ]; then
    [ -f "$checkpoint.slc" ] || fail "no checkpoint of frame $half"
    expected="resuming from" label="stopped over $np1 processes at frame $half, resumed over $np2"
  else
    parts=$(find "$work/resumed" -name "$(basename "$checkpoint").rank*.slc" | wc -l)
    [ "$parts" -eq "$np1" ] || fail "$parts checkpoint parts of frame $half, expected $np1"
    [ ! -e "$checkpoint.slc" ] || fail "a per-rank run wrote a whole checkpoint"
    expected="resuming from .*$(basename "$checkpoint").rank0.slc"
    label="per-rank checkpoints of $np1 processes at frame $half ($parts parts), resumed over $np2"
  fi
  split_run "$np2" "$work/resumed" --frames "$frames" --resume --quiet || fail "mpirun -np $np2 --resume failed"
  grep -q "$expected" "$work/resumed.log" || { cat "$work/resumed.log"; fail "the second run did not resume ($expected)"; }
  if [ "$mode" = per_rank_resume ]; then
    "$cli" merge "$work/resumed" > "$work/merge.log" 2>&1 || { cat "$work/merge.log"; fail "slurry merge failed"; }
  fi
  # The first run's scene is the copy: the one-process run of the same copy is the reference.
  rm -rf "$work/one"
  "$cli" run "$scene" --out "$work/one" --frames "$frames" --threads 1 --quiet > "$work/one.log" 2>&1 || fail "the one-process run failed"
  compare "$work/resumed" "$label"
  exit 0
fi

if [ "${1:-}" = per_rank ]; then
  np=$2
  sed 's/"output": {/"output": { "per_rank": true,/' "$scene" > "$work/$name.json"
  scene="$work/$name.json"
  mkdir -p "$work/parts"
  split_run "$np" "$work/parts" --frames "$frames" || fail "mpirun -np $np with output.per_rank failed"
  [ ! -e "$work/parts/frame_0000.ply" ] || fail "a per-rank run wrote a whole frame"
  parts=$(find "$work/parts" -name 'frame_*.rank*.ply' | wc -l)
  [ "$parts" -eq $(((frames + 1) * np)) ] || fail "$parts per-rank files, expected $(((frames + 1) * np))"
  # A frame with a part missing is refused, naming the file, and nothing is written for it.
  mkdir -p "$work/broken"
  cp "$work/parts/frame_0001.rank0.ply" "$work/broken/"
  set +e
  "$cli" merge "$work/broken" > "$work/broken.log" 2>&1
  rc=$?
  set -e
  [ "$rc" -eq 3 ] || { cat "$work/broken.log"; fail "merging an incomplete frame exited $rc, expected 3"; }
  grep -q "frame_0001.rank1.ply: missing" "$work/broken.log" || { cat "$work/broken.log"; fail "no message naming the missing part"; }
  [ ! -e "$work/broken/frame_0001.ply" ] || fail "an incomplete frame was merged"
  "$cli" merge "$work/parts" > "$work/merge.log" 2>&1 || { cat "$work/merge.log"; fail "slurry merge failed"; }
  [ "$(find "$work/parts" -name 'frame_*.rank*.ply' | wc -l)" -eq 0 ] || fail "slurry merge left per-rank files"
  rm -rf "$work/one"
  "$cli" run "$scene" --out "$work/one" --frames "$frames" --threads 1 --quiet > "$work/one.log" 2>&1 || fail "the one-process run failed"
  compare "$work/parts" "mpirun -np $np, per-rank files merged ($parts parts)"
  exit 0
fi

for spec in "$@"; do
  # NP, or NP:GRID to require the processes per axis (GRID as the log prints it, e.g. 2x2x1).
  np=${spec%%:*} grid=
  [ "$spec" = "$np" ] || grid=${spec#*:}
  mkdir -p "$work/np$np"
  split_run "$np" "$work/np$np" --frames "$frames" || fail "mpirun -np $np failed"
  if [ "$np" -gt 1 ]; then
    line=$(grep -m1 -o "$np ranks in [0-9 x]* boxes: .*" "$work/np$np.log" || true)
    [ -n "$line" ] || { cat "$work/np$np.log"; fail "mpirun -np $np: the log names no split over $np ranks"; }
    if [ -n "$grid" ]; then
      want="$np ranks in ${grid//x/ x } boxes:"
      [ "${line#"$want"}" != "$line" ] || fail "mpirun -np $np: split as '${line%%:*}', expected '$want'"
    fi
    last=$(grep -o "$np ranks in [0-9 x]* boxes: .*" "$work/np$np.log" | tail -1)
    echo "$name: np $np, last frame: $last"
  fi
  compare "$work/np$np" "mpirun -np $np"
done
