#!/usr/bin/env bash
# Runs scripts/Snakefile on a small synthetic site with `snakemake --cores 2` and checks that
# the per-scan jobs give byte-identical results to one `mvao merge`. Skips (exit 0, with the
# reason) when snakemake is not installed. Usage: scripts/test_snakefile.sh [MVAO_BINARY]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
mvao="${1:-$here/../target/release/mvao}"
snakemake="${SNAKEMAKE:-snakemake}"
if ! command -v "$snakemake" >/dev/null 2>&1; then
    echo "skipped: snakemake not found (pip install snakemake, or set SNAKEMAKE)"
    exit 0
fi
mvao="$(cd "$(dirname "$mvao")" && pwd)/$(basename "$mvao")"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"$mvao" synth --stations 3 --width 160 --height 80 -o "$tmp/site" 2>/dev/null
"$mvao" merge -q --no-preview --radius 0.2 -o "$tmp/whole" "$tmp"/site/*.ply
"$snakemake" -q -s "$here/Snakefile" --cores 2 -d "$tmp" \
    --config scans="$tmp/site/*.ply" out="$tmp/jobs" mvao="$mvao" args="--radius 0.2 --no-preview" \
    >"$tmp/snakemake.log" 2>&1 || { cat "$tmp/snakemake.log"; exit 1; }
for f in "$tmp"/whole/*.mvao.ply; do
    cmp "$f" "$tmp/jobs/$(basename "$f")"
done
echo "ok: $(ls "$tmp"/jobs/*.mvao.ply | wc -l) scans, per-scan jobs identical to one merge"
