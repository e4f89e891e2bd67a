#!/usr/bin/env bash
# Set up .venv/ if needed, then delight the bundled scene headless into out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
scene=blend_fixtures/lambert_sky/scene.blend
if [ ! -f "$scene" ]; then
  echo "rendering the bundled scene once (Cycles, about a minute)..."
  .venv/bin/python blend_fixtures/make_fixtures.py --only lambert_sky
fi
mkdir -p out
.venv/bin/python -m blender_addon "$scene" --object Subject --out out/demo --overwrite "$@"
echo "wrote out/demo/ (open the EXRs in Blender or any EXR viewer)"
