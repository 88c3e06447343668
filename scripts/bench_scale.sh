#!/usr/bin/env bash
# Overnight-scale benchmark: a synthetic site of many TLS stations run end to end under a
# memory budget. Prints points/s, per-stage times, peak RSS and the time extrapolated to the
# paper's castle (317 M points).
#
#   scripts/bench_scale.sh [STATIONS=24] [WIDTH=1440] [HEIGHT=720] [BUDGET=2G] [DIR=bench-scale] [SCENE=suite]
#   scripts/bench_scale.sh survey [STATIONS=6] [DIR=bench-scale]
#
# `survey` is shaped like a real survey: courtyard stations of 2048×1024 with open sky
# (unfilled pixels) and no normals in the files, so the run estimates them, under a 1G budget.
# SYNTH_OPTS adds options to `mvao synth` (`--no-normals`, …; `--no-grid` for a survey whose
# files, like many exports, lost the scanner's grid).
#
# REPEAT=N runs the job N times on the same site and prints every run and the range and
# median: on a shared machine one run's time says little.
#
# 24 stations of 1440×720 are about 25 M points (0.8 GB of PLY); 50 stations make 52 M.
# SCENE `suite` is a row of rooms joined by doorways, four stations to a room, so each scan
# overlaps its neighbours' as on a real site; `room` puts every station in one room, where every
# scan overlaps every other (the merge's worst case).
#
#   scripts/bench_scale.sh small [DIR=bench-scale]
#
# The many-small-scans suite: 15 perspective views of 208×156 along the `vault` mesh scene,
# about 29 k points each (0.44 M in all), gridded, no normals in the files.
set -euo pipefail
synth_opts="${SYNTH_OPTS:-}"
suite=scale
if [ "${1:-}" = survey ]; then
    stations="${2:-6}"; width=2048; height=1024; budget=1G
    dir="${3:-bench-scale}"; scene=courtyard; synth_opts="--no-normals $synth_opts"
elif [ "${1:-}" = small ]; then
    suite=small; stations=15; width=208; height=156; budget=2G
    dir="${2:-bench-scale}"; scene=vault
else
    stations="${1:-24}"; width="${2:-1440}"; height="${3:-720}"; budget="${4:-2G}"
    dir="${5:-bench-scale}"; scene="${6:-suite}"
fi
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here/.."
cargo build --release -q
mvao="$PWD/target/release/mvao"
mkdir -p "$dir"
tag="$(printf '%s' "$synth_opts" | tr -c 'a-z0-9' '-' | sed 's/--*/-/g; s/-$//')"
site="$dir/site-$scene-$stations-${width}x$height$tag"
if [ "$suite" = small ] && [ ! -f "$site/alignment.mlp" ]; then
    rm -rf "$site"
    at=()
    for k in $(seq 0 14); do
        at+=("--at=$(awk -v k="$k" 'BEGIN { printf "%.2f,%.1f,1.5", -2 + 0.65 * k, k % 2 ? -0.7 : 0.7 }')")
    done
    "$mvao" synth --scene vault --stations 15 --projection perspective --width 208 --height 156 \
        --no-normals "${at[@]}" -o "$site"
fi
if [ ! -f "$site/alignment.mlp" ]; then
    rm -rf "$site"
    "$mvao" synth --scene "$scene" --stations "$stations" --width "$width" --height "$height" \
        $synth_opts -o "$site"
fi
repeat="${REPEAT:-1}"
for run in $(seq 1 "$repeat"); do
    rm -rf "$dir/out"
    /usr/bin/time -v "$mvao" merge -q --no-preview --radius 0.2 --tmax 0.4 --max-memory "$budget" \
        -o "$dir/out" "$site"/*.ply 2>"$dir/time-$run.log"
    cp "$dir/out/report.json" "$dir/report-$run.json"
done
python3 - "$dir" "$budget" "$site" "$repeat" <<'PY'
import json, re, statistics, sys
d, budget, site, repeat = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
runs = []
for i in range(1, repeat + 1):
    r = json.load(open(f"{d}/report-{i}.json"))
    log = open(f"{d}/time-{i}.log").read()
    cpu = sum(float(re.search(rf"{k} time \(seconds\): ([0-9.]+)", log).group(1))
              for k in ("User", "System"))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", log).group(1)) * 1024
    runs.append((r, cpu, rss))
def line(r, cpu, rss):
    wall, pts = r["totals"]["wall_s"], r["totals"]["points"]
    return (f"{wall:.1f} s = {pts/wall/1e6:.2f} M points/s, CPU {cpu:.1f} s = "
            f"{cpu/wall:.2f} cores busy, {cpu/(pts/1e6):.2f} CPU-s per M points, "
            f"peak RSS {rss/2**30:.2f} GiB")
r, cpu, rss = runs[-1]
wall, pts = r["totals"]["wall_s"], r["totals"]["points"]
print(f"{len(r['scans'])} scans, {pts/1e6:.1f} M points, budget {budget}, {site}")
print("occlusion: average (the default mode), --radius 0.2 --tmax 0.4")
print(f"end to end: {wall:.1f} s = {pts/wall/1e6:.2f} M points/s")
for k, v in sorted(r["timings_s"].items(), key=lambda kv: -kv[1]):
    print(f"  {k:<10} {v:8.1f} s")
# CPU time varies less than wall time on a shared machine.
print(f"CPU: {cpu:.1f} s user+system = {cpu/wall:.2f} cores busy, {cpu/(pts/1e6):.2f} CPU-s per M points")
print(f"peak RSS: {rss/2**30:.2f} GiB (time -v), {r['peak_rss_bytes']/2**30:.2f} GiB (report)")
print(f"maps loaded by the merge: {r['map_loads']} (views kept from the prepare pass: {r['views_kept']}); pairs kept {r['plan']['pairs_kept']}, skipped {r['plan']['pairs_skipped']}")
print("bytes read: " + ", ".join(f"{k} {v/2**30:.2f} GiB" for k, v in r["bytes_read"].items()))
print(f"extrapolated to 317 M points at this rate: {317e6/(pts/wall)/3600:.2f} h")
if repeat > 1:
    print(f"{repeat} runs:")
    for i, run in enumerate(runs, 1):
        print(f"  {i:>2}: " + line(*run))
    rates = [x[0]["totals"]["points"] / x[0]["totals"]["wall_s"] / 1e6 for x in runs]
    per_m = [x[1] / (x[0]["totals"]["points"] / 1e6) for x in runs]
    print(f"M points/s: {min(rates):.2f}-{max(rates):.2f}, median {statistics.median(rates):.2f}; "
          f"runs at 1 M points/s or more: {sum(v >= 1.0 for v in rates)} of {repeat}")
    print(f"CPU-s per M points: {min(per_m):.2f}-{max(per_m):.2f}, median {statistics.median(per_m):.2f}")
    print(f"peak RSS: {min(x[2] for x in runs)/2**30:.2f}-{max(x[2] for x in runs)/2**30:.2f} GiB")
PY
