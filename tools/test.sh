#!/usr/bin/env bash
# Set up .venv/ if needed, then run every test (core, then real Blender through bpy).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export OPENBLAS_NUM_THREADS=1
exec .venv/bin/python -m pytest -q "$@"
