#!/usr/bin/env bash
# Set up the venvs if needed, then run every test on Blender 5.2 (core, then real Blender through bpy)
# and the Blender tier (tests/bpy) on Blender 4.2. Arguments go to both pytest runs:
#
#   bash tools/test.sh                       # everything
#   bash tools/test.sh -k bake               # the tests matching "bake", on both Blenders
#   BLENDERS=5.2 bash tools/test.sh tests/test_exr.py
set -euo pipefail
cd "$(dirname "$0")/.."
read -r -a blenders <<< "${BLENDERS:-5.2 4.2}"
bash tools/setup.sh "${blenders[@]}"
export OPENBLAS_NUM_THREADS=1
status=0
echo "== ruff: lint and format"
venv=.venv; [[ " ${blenders[*]} " == *" 5.2 "* ]] || venv=.venv-4.2
"$venv/bin/ruff" check . || status=$?
"$venv/bin/ruff" format --check . || status=$?
for b in "${blenders[@]}"; do
  case "$b" in
    5.2) echo "== Blender 5.2 (.venv): the whole suite"
         .venv/bin/python -m pytest -q "$@" || status=$? ;;
    4.2) echo "== Blender 4.2 (.venv-4.2): tests/bpy"
         .venv-4.2/bin/python -m pytest -q tests/bpy "$@" || status=$? ;;
  esac
done
exit $status
