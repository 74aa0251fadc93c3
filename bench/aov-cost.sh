#!/usr/bin/env bash
# What `--aov albedo,normal,depth` costs a local render: each scene rendered with and without
# it, alternately, ROUNDS times, timed around the whole `tessera render` (load, render, EXR),
# on every core. Writes docs/benchmarks/aov-cost.md. The AOVs come from a pass of their own
# (one more camera ray per sample and its delta bounces), so the cost is that pass.
# Usage: bench/aov-cost.sh [ROUNDS] [SPP]
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-5}
spp=${2:-64}
cargo build --release -q -p tessera-cli --features bench
bin=target/release/tessera
out=docs/benchmarks/aov-cost.md
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
scenes=(scenes/cornell-box.toml scenes/glass-mirror.toml scenes/materials.toml scenes/gltf-metals.toml)
seconds() { # seconds for one render: $1 scene, then extra flags
    local scene=$1
    shift
    local t0 t1
    t0=$(date +%s.%N)
    "$bin" render "$scene" --spp "$spp" --output "$tmp/out.exr" "$@" >/dev/null 2>&1
    t1=$(date +%s.%N)
    awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}'
}
median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
{
    echo "# The cost of AOVs ($(date -u +%Y-%m-%d))"
    echo
    echo "Command: \`bench/aov-cost.sh $rounds $spp\`: each scene rendered by \`tessera render SCENE --spp $spp\`"
    echo "with and without \`--aov albedo,normal,depth\`, alternately, $rounds rounds, every core; the time is"
    echo "the whole command's (load, render, EXR). Machine: $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores."
    echo
    echo "| scene | without (median s) | with (median s) | with / without |"
    echo "|---|---:|---:|---:|"
} >"$out"
for scene in "${scenes[@]}"; do
    "$bin" render "$scene" --spp 1 --output "$tmp/warm.exr" >/dev/null 2>&1 # page cache, tables
    : >"$tmp/plain"
    : >"$tmp/aov"
    for _ in $(seq "$rounds"); do
        seconds "$scene" >>"$tmp/plain"
        seconds "$scene" --aov albedo,normal,depth >>"$tmp/aov"
    done
    p=$(median <"$tmp/plain")
    a=$(median <"$tmp/aov")
    printf '| %s | %.3f | %.3f | %.3f |\n' "$(basename "$scene" .toml)" "$p" "$a" "$(awk -v a="$a" -v p="$p" 'BEGIN {print a / p}')" >>"$out"
done
cat "$out"
