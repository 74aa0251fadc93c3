#!/usr/bin/env bash
# Installs Debian's chromium for the dashboard's browser test (crates/cli/tests/browser.rs),
# unless a chromium is on PATH already.
set -euo pipefail
command -v chromium >/dev/null 2>&1 && exit 0
SUDO=
[[ $(id -u) == 0 ]] || SUDO=sudo
echo "== installing chromium from Debian's packages"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get install -y -q --no-install-recommends chromium >/dev/null 2>&1 \
  || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q --no-install-recommends chromium >/dev/null; } \
  || { echo "chromium is missing and could not be installed" >&2; exit 1; }
chromium --version
