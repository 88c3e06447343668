#!/usr/bin/env bash
# Scores `mvao reference` (surfels and grid triangles) against the exact ground truth of the
# built-in mesh scenes, noise-free and with range noise, registration error and estimated
# normals; the figures of docs/reference.md. Usage: scripts/reference_truth.sh [OUT_DIR]
# Environment: WIDTH HEIGHT (equirect map of the buildings, default 720 x 360), RELIEF_WIDTH
# RELIEF_HEIGHT (perspective views of the relief, default 480 x 360), RAYS (default 128, the
# same for the truth so both cast the same directions when normals are exact).
set -euo pipefail
out=${1:-reference-truth}
W=${WIDTH:-720}
H=${HEIGHT:-360}
RW=${RELIEF_WIDTH:-480}
RH=${RELIEF_HEIGHT:-360}
R=${RAYS:-128}
cargo build --profile test --example reference_truth
bin=target/debug/examples/reference_truth
run() {
  local label=$1
  shift
  local line
  line=$("$bin" "$@" rays="$R" truth_rays="$R" out="$out/tmp" | grep "joint all:")
  echo "$label | $line"
}
mkdir -p "$out"
{
  for scene in colonnade vault porch; do
    for t in 0.4 inf; do
      for g in surfels mesh; do
        run "$scene t_max=$t $g exact" "$scene" tmax="$t" geometry="$g" width="$W" height="$H"
      done
      run "$scene t_max=$t surfels noise 2mm reg 2mm/0.05deg no normals" "$scene" tmax="$t" \
        width="$W" height="$H" noise=0.002 reg=0.002,0.05 normals=0
    done
  done
  for t in 0.005 inf; do
    for g in surfels mesh; do
      run "relief t_max=$t $g exact" relief model=perspective width="$RW" height="$RH" tmax="$t" geometry="$g"
    done
    run "relief t_max=$t surfels noise 0.05mm no normals" relief model=perspective width="$RW" \
      height="$RH" tmax="$t" noise=0.00005 normals=0
  done
} | tee "$out/table.txt"
