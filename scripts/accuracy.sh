#!/usr/bin/env bash
# Regenerates the figures of docs/accuracy.md: the synthetic TLS room (three
# 800×400 stations, 0.96 M points, --radius 0.2 --tmax 0.4) and the bundled bunny (ten
# scans, --radius 0.02 --tmax 0.04): ray-traced references, the sweep of both estimators
# (SSAO only and MVAO N = 1, 3, 5; on the bunny the union at 8 rays too), and, when
# pymeshlab is installed (MVAO_PYTHON=path/to/python with pymeshlab), MeshLab's ambient
# occlusion on the bunny, scored at t_max = ∞ (its own quantity) and added to the bunny's CSV.
# The bunny is scored against rays at its reconstructed surface (`reference --surface`);
# its surfel reference is scored against that truth too.
#
#   scripts/accuracy.sh [DIR=accuracy]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here/.."
dir="${1:-accuracy}"
cargo build --release -q
mvao="$PWD/target/release/mvao"
mkdir -p "$dir"

# Synthetic room: analytic and surfel references, sweep.
"$mvao" synth --scene room --stations 3 --width 800 --height 400 -o "$dir/room" \
    --reference-rays 128 --reference-tmax 0.4
"$mvao" reference -q --force --tmax 0.4 --rays 128 -o "$dir/room-ref" "$dir"/room/*.ply
"$mvao" eval --reference "$dir/room/reference-analytic" "$dir"/room-ref/*.ref.ply | tail -1 \
    | sed 's/^/surfel reference vs exact geometry: /'
"$mvao" sweep --force --radius 0.2 --tmax 0.4 --dataset "synthetic room 3 stations" \
    --reference "$dir/room-ref" -o "$dir/room-sweep" "$dir"/room/*.ply

# Bunny: the truth at its reconstruction, its surfel reference against it, sweep.
bunny=(fixtures/stanford-bunny/*.ply)
surface=fixtures/stanford-bunny/reconstruction/bun_zipper.ply
"$mvao" reference -q --force --tmax 0.04 --rays 256 --surface "$surface" -o "$dir/bunny-truth" \
    "${bunny[@]}"
"$mvao" reference -q --force --tmax 0.04 --rays 256 -o "$dir/bunny-ref" "${bunny[@]}"
"$mvao" eval --reference "$dir/bunny-truth" "$dir"/bunny-ref/*.ref.ply | tail -1 \
    | sed 's/^/bunny surfel reference vs its reconstruction: /'
"$mvao" sweep --force --radius 0.02 --tmax 0.04 --dataset "bunny 10 scans" --union-rays 8 \
    --reference "$dir/bunny-truth" -o "$dir/bunny-sweep" "${bunny[@]}"
py="${MVAO_PYTHON:-python3}"
if QT_QPA_PLATFORM=offscreen "$py" -c "import pymeshlab" 2>/dev/null; then
    # pymeshlab computes plain ambient occlusion: mvao is swept at the same quantity
    # (t_max = inf, no falloff) against a reference of it, and pymeshlab's row joins that sweep.
    "$mvao" reference -q --force --tmax inf --falloff none --rays 256 --surface "$surface" \
        -o "$dir/bunny-ref-inf" "${bunny[@]}"
    "$mvao" sweep --force --quick --radius 0.02 --tmax inf --falloff none \
        --dataset "bunny 10 scans, t_max inf" --reference "$dir/bunny-ref-inf" \
        -o "$dir/bunny-sweep-inf" "${bunny[@]}"
    QT_QPA_PLATFORM=offscreen "$py" scripts/compare_pymeshlab.py "${bunny[@]}" \
        -o "$dir/bunny-pymeshlab" --force
    wall=$("$py" -c "import json,sys; print(json.load(open(sys.argv[1]))['timings_s']['filter'])" \
        "$dir/bunny-pymeshlab/pymeshlab.json")
    "$mvao" eval --reference "$dir/bunny-ref-inf" --csv "$dir/bunny-sweep-inf/sweep.csv" \
        --dataset "bunny 10 scans, t_max inf" --method pymeshlab --directions 64 --wall-s "$wall" \
        "$dir"/bunny-pymeshlab/*.pymeshlab.ply | tail -1 | sed 's/^/pymeshlab vs t_max = inf truth: /'
    "$mvao" plot "$dir/bunny-sweep-inf/sweep.csv" \
        --title "bunny 10 scans, plain AO (t_max inf): e_A against wall time"
else
    echo "pymeshlab not importable by $py: its row is left out (see scripts/README.md)"
fi
echo "CSV and SVG in $dir/room-sweep, $dir/bunny-sweep and $dir/bunny-sweep-inf"
