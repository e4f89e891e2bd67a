#!/usr/bin/env bash
# Set up .venv/ (Blender 5.2) if needed, then delight the bundled scene headless into out/demo/ and draw its pictures.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh 5.2
scene=blend_fixtures/lambert_sky/scene.blend
if [ ! -f "$scene" ]; then
  echo "rendering the bundled scene once (Cycles, about a minute)..."
  .venv/bin/python blend_fixtures/make_fixtures.py --only lambert_sky
fi
mkdir -p out
# 512^2 like the fixture's ground truth: its 13 photos of 320x240 cannot fill more texels (and it is 4x faster).
.venv/bin/python -m blender_addon "$scene" --object Subject --texture-size 512 --out out/demo --overwrite "$@"
.venv/bin/python tools/demo_pictures.py out/demo --fixture "$(dirname "$scene")"
echo "wrote out/demo/ (the albedo and per-view EXRs; pictures in out/demo/pictures/)"
