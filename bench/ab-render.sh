#!/usr/bin/env bash
# Same-sitting A/B of `tessera render` wall time: the baseline binary ($1) against the new ($2),
# interleaved (the order alternates each round), the EXRs compared by cmp. Scenes after the
# third argument replace the default four (e.g. `bench/ab-render.sh A B 5 envmap-balls.toml`); a
# scene with a slash in its name is a path from the repository root (e.g. the skies of
# bench/make_big_sky.py).
set -euo pipefail
old=$1; new=$2; rounds=${3:-5}
shift $(( $# < 3 ? $# : 3 ))
cd "$(dirname "$0")/.."
declare -A spp=([cornell-box.toml]=512 [materials.toml]=192 [gltf-metals.toml]=192 [glass-mirror.toml]=256)
scenes=("$@")
(( ${#scenes[@]} )) || scenes=(cornell-box.toml materials.toml gltf-metals.toml glass-mirror.toml)
for s in "${scenes[@]}"; do
  file=scenes/$s; [[ $s == */* ]] && file=$s && s=$(basename "$s")
  for r in $(seq "$rounds"); do
    if (( r % 2 )); then order="old new"; else order="new old"; fi
    for which in $order; do
      bin=$old; [[ $which == new ]] && bin=$new
      t0=$(date +%s.%N)
      "$bin" render "$file" --spp "${spp[$s]:-192}" --output "/tmp/ab-$which-$s.exr" >/dev/null 2>&1
      t1=$(date +%s.%N)
      echo "$s $which $(echo "$t1 - $t0" | bc)"
    done
  done
  cmp "/tmp/ab-old-$s.exr" "/tmp/ab-new-$s.exr" && echo "$s same bits"
done
