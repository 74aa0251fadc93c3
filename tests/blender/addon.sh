#!/usr/bin/env bash
# The Blender add-on (blender/tessera) against a real coordinator and worker, headless (#83):
# tests/blender/addon.py installs the add-on's zip into Blender (PyPI's bpy, set up in
# target/blender-venv as tests/blender/run.sh does), builds a scene, renders its current frame
# (denoised) and a three-frame range through the add-on, and checks what an artist sees when things fail;
# then every frame the add-on saved must be, byte for byte, `tessera render` of the scene
# files it exported. Run from anywhere: `tests/blender/addon.sh`.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/blender-venv
tests/blender/bpy-venv.sh
cargo build --release --workspace -q
scripts/install-oidn.sh
T=$PWD/target/release/tessera
out=$PWD/target/blender-addon
rm -rf "$out"
mkdir -p "$out"
scripts/build-blender-addon.sh "$out/tessera-blender.zip" >/dev/null

token=addon-test-token
TESSERA_TOKEN=$token "$T" coordinator --listen 127.0.0.1:0 --http 127.0.0.1:0 \
    --denoise --max-spp 1000 --data-dir "$out/farm" >"$out/coord.out" 2>"$out/coord.err" &
farm=("$!")
trap 'kill "${farm[@]}" 2>/dev/null || true' EXIT
for _ in $(seq 100); do grep -q "dashboard on" "$out/coord.out" && break; sleep 0.1; done
grpc="http://$(sed -n 's/listening on //p' "$out/coord.out")"
http=$(sed -n 's/dashboard on //p' "$out/coord.out")
http=${http%/}
TESSERA_TOKEN=$token TESSERA_COORDINATOR=$grpc "$T" worker --threads 2 --name blender 2>"$out/worker.err" &
farm+=("$!")

# Blender's own settings and extensions go in a folder of the test's, not the user's.
BLENDER_USER_RESOURCES=$out/blender-user "$venv/bin/python" tests/blender/addon.py -- \
    "$out/tessera-blender.zip" "$http" "$token" "$out" 2>&1 | tee "$out/addon.log" | grep "^addon:" \
    || { cat "$out/addon.log" "$out/coord.err" >&2; exit 1; }
grep -q "^addon: ok" "$out/addon.log"

count=0
while read -r toml exr; do
    "$T" render "$toml" --spp 8 --output "$out/local.exr" >/dev/null
    cmp "$exr" "$out/local.exr" || { echo "$exr differs from tessera render $toml" >&2; exit 1; }
    count=$((count + 1))
done <"$out/frames.txt"
[ "$count" = 4 ] || { echo "expected 4 frames, compared $count" >&2; exit 1; }
# The cube moves: the range's frames are three exports, not one.
if cmp -s "$out/tessera/shot.0001.exr" "$out/tessera/shot.0003.exr"; then
    echo "frames 1 and 3 are the same image" >&2; exit 1
fi
echo "addon: the 4 frames the add-on saved are tessera render's bytes"
