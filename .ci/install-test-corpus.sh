#!/usr/bin/env bash
# Installs Debian's assimp-testmodels, the mesh corpus of crates/render/tests/mesh_corpus.rs
# (under /usr/share/assimp/models), unless it is there already.
set -euo pipefail
[[ -d /usr/share/assimp/models/OBJ ]] && exit 0
SUDO=
[[ $(id -u) == 0 ]] || SUDO=sudo
echo "== installing assimp-testmodels from Debian's packages"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get install -y -q --no-install-recommends assimp-testmodels >/dev/null 2>&1 \
  || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q --no-install-recommends assimp-testmodels >/dev/null; } \
  || { echo "assimp-testmodels is missing and could not be installed" >&2; exit 1; }
