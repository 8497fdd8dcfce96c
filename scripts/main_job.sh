#!/usr/bin/env bash
# The main job: set up a fresh Debian 12 machine, build, then run the paper's
# experiment (the endoscope tilt beta swept from 0 to 55 deg) on
# blend_scenes/flat_tissue.blend inside Blender, and write out/main_job/:
# sweep CSV + JSON, plots, report.md, and a .blend + Cycles render for one beta.
# Both sweeps (flat_tissue.blend, and colon_polyp.blend into out/main_job/colon_polyp/) render the
# endoscope's view per beta: views/, views_contact_sheet.png, visibility.png and the report's answer to
# "at which beta is the polyp most visible" (docs/render.md).
# STORE (default 250000 fluorescent photons per beta) sets the size.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT="${OUT:-out/main_job}"
STORE="${STORE:-250000}"
export ENDOPHOTON_ADDON_PATH="$PWD/addon"
mkdir -p "$OUT"
start=$(date +%s)
echo "== beta sweep on blend_scenes/flat_tissue.blend (store $STORE per beta)"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/flat_tissue.blend --store "$STORE" --out "$OUT" \
  --target Polyp --background Tissue
echo "== beta sweep on blend_scenes/colon_polyp.blend: the endoscope's view per beta, polyp against the colon wall"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend --store "$STORE" --out "$OUT/colon_polyp" \
  --target Polyp --background Colon
test -f "$OUT/colon_polyp/views_contact_sheet.png" && test -f "$OUT/colon_polyp/visibility.png"
echo "== one beta as a Blender scene with point cloud, volume and a Cycles render"
blender -b blend_scenes/flat_tissue.blend --python-exit-code 1 --python scripts/main_job_scene.py -- \
  --out "$OUT" --beta 30 --store 100000 2>&1 | grep -v "^Fra:" || true
test -f "$OUT/render_beta30.png"
echo "== done in $(( $(date +%s) - start )) s: $OUT/report.md"
ls "$OUT"
