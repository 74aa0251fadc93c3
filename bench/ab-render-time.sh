#!/usr/bin/env bash
# Same-sitting A/B of render time (what `tessera render` prints as "in X s": the render alone,
# without loading the scene) of a baseline binary ($1) against a new one ($2), alternated for
# $3 rounds at $4 spp, then per scene the medians, the median ratio new/old, the range of the
# paired ratios, and whether the last EXRs are the same bytes (cmp). A scene is a bundled one
# by name (`envmap-balls`) or a path (the scenes of bench/make_probe_scenes.py). Unlike
# bench/ab-render.sh, which prints each run's wall time with the scene's load, this times the
# render alone and summarises, for steps of a few percent on the render loop:
#
#   bench/ab-render-time.sh OLD NEW 6 128 envmap-balls target/bench-cache/probe/v3-point-pbr.toml
#
# OLD and NEW may carry `render` flags after the binary, to time two settings of one binary
# (the same bits are then expected too):
#
#   bench/ab-render-time.sh "target/release/tessera --tracer scalar" target/release/tessera 6 64 envmap-balls
set -euo pipefail
old=$1; new=$2; rounds=$3; spp=$4
shift 4
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
seconds() {
  local cmd
  read -ra cmd <<< "$1"
  "${cmd[0]}" render "$2" --spp "$spp" --output "$3" "${cmd[@]:1}" 2>&1 | grep -o 'in [0-9.]* s' | awk '{print $2}'
}
for s in "$@"; do
  file=scenes/$s.toml; [[ $s == */* ]] && file=$s
  a=(); b=()
  for _ in $(seq "$rounds"); do
    a+=("$(seconds "$old" "$file" "$tmp/old.exr")")
    b+=("$(seconds "$new" "$file" "$tmp/new.exr")")
  done
  same=$(cmp -s "$tmp/old.exr" "$tmp/new.exr" && echo same || echo DIFFERENT)
  python3 - "$(basename "$s" .toml)" "$same" "${a[*]}" "${b[*]}" <<'PY'
import statistics as st
import sys
name, same, a, b = sys.argv[1], sys.argv[2], sys.argv[3].split(), sys.argv[4].split()
a, b = [float(x) for x in a], [float(x) for x in b]
r = sorted(y / x for x, y in zip(a, b))
print(f"{name}: old {st.median(a):.3f} s, new {st.median(b):.3f} s, ratio {st.median(b) / st.median(a):.3f}"
      f" (paired {r[0]:.3f}-{r[-1]:.3f}), bits {same}")
PY
done
