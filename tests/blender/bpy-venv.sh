#!/usr/bin/env bash
# Sets up Blender as a Python module (PyPI's bpy 4.5, Python 3.11) in target/blender-venv once
# (a download of about 400 MB), for tests/blender/run.sh, tests/blender/addon.sh and
# bench/cycles-vs-tessera.sh. Run from the repository root.
set -euo pipefail
venv=target/blender-venv
if [ ! -x "$venv/bin/python" ]; then
    python3.11 -m venv "$venv"
    "$venv/bin/pip" install --quiet "bpy==4.5.*"
fi
