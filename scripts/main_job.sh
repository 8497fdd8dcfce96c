#!/usr/bin/env bash
# The main job: set up a fresh Debian 12 machine, build, then run the paper's
# experiment (the endoscope tilt beta swept from 0 to 55 deg) on
# blend_scenes/flat_tissue.blend inside Blender, and write out/main_job/:
# sweep CSV + JSON, plots, report.md, and a .blend + Cycles render for one beta.
# The sweeps render the endoscope's view per beta (views/, views_contact_sheet.png, visibility.png and the
# report's answer to "at which beta is the polyp most visible", docs/render.md). Every beta runs with a seed
# of its own, so the report's test of "varies with beta" holds its level.
# The colon (colon_polyp.blend) is swept twice, under white light (out/main_job/colon_polyp/) and under the
# 405 nm blue light of photodynamic diagnosis with the long-pass fluorescence filter (colon_polyp_blue/).
# Both measure the polyp against the wall in an 8-pixel ring around it (the whole Colon region beside it:
# surround_vs_region.png) and run each beta until the colour contrast (red/green, camera channels) has a
# standard error <= ERR (0.05), or until CAP packets are behind its image; report.md ends with the answer
# on the colon under each light, its errors and the paper's 34 deg (scripts/main_job_answer.py).
# The white-light colon's views come from the next-event estimate (unbiased, docs/sweep.md), which reaches ERR
# at every beta within CAP; the blue and spectral colon sweeps use the kernel estimate up to OTHER_CAP packets
# (they do not reach ERR at an affordable cap with either estimator; docs/performance.md section 19). The colon
# sweeps run every 10 deg (COLON_BETAS), so the whole job stays within 10 minutes on 2 idle cores.
# STORE (default 250000 fluorescent photons per beta) sets the paper's store N; BETAS the flat scene's angles;
# ERR and CAP the white colon's target; ESTIMATOR the other sweeps' camera estimator (empty: the kernel
# estimate), COLON_ESTIMATOR the white-light colon's (default nee).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT="${OUT:-out/main_job}"
STORE="${STORE:-250000}"
BETAS="${BETAS:-0:60:5}"
ERR="${ERR:-0.05}"
CAP="${CAP:-4000000}"
OTHER_CAP="${OTHER_CAP:-750000}"
COLON_BETAS="${COLON_BETAS:-0:60:10}"
ESTIMATOR="${ESTIMATOR:-}"
COLON_ESTIMATOR="${COLON_ESTIMATOR:-nee}"
export ENDOPHOTON_ADDON_PATH="$PWD/addon"
mkdir -p "$OUT"
start=$(date +%s)
VIEW=(--view-size 128)
if [ -n "$ESTIMATOR" ]; then VIEW+=(--estimator "$ESTIMATOR"); fi
COLON=(--betas "$COLON_BETAS" --store "$STORE" --target Polyp --background Colon --surround 8
  --target-contrast "red_green_camera:$ERR" "${VIEW[@]}")
echo "== beta sweep on blend_scenes/flat_tissue.blend (store $STORE per beta)"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/flat_tissue.blend --betas "$BETAS" --store "$STORE" \
  --out "$OUT" --target Polyp --background Tissue "${VIEW[@]}"
echo "== colon_polyp.blend, white light: the polyp against its surround, to a colour-contrast error of $ERR"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend --out "$OUT/colon_polyp" "${COLON[@]}" \
  --max-packets "$CAP" --estimator "$COLON_ESTIMATOR"
echo "== colon_polyp.blend, blue light (405 nm, photodynamic diagnosis), long-pass fluorescence filter"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend --out "$OUT/colon_polyp_blue" \
  --light blue "${COLON[@]}" --max-packets "$OTHER_CAP"
LIGHTS=("white=$OUT/colon_polyp" "blue=$OUT/colon_polyp_blue")
# The spectral colon (issue 35, `ep.media`: wall of colon mucosa, polyp of adenomatous polyp) is swept too,
# under white light; its answer joins the comparison. SPECTRAL=0 skips it.
if [ "${SPECTRAL:-1}" = 1 ] && [ -f blend_scenes/colon_polyp_spectral.blend ]; then
  echo "== colon_polyp_spectral.blend (spectral mucosa and polyp), white light"
  /usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp_spectral.blend \
    --out "$OUT/colon_polyp_spectral" "${COLON[@]}" --max-packets "$OTHER_CAP"
  LIGHTS+=("spectral tissue, white=$OUT/colon_polyp_spectral")
fi
test -f "$OUT/colon_polyp/views_contact_sheet.png" && test -f "$OUT/colon_polyp/visibility.png"
test -f "$OUT/colon_polyp/surround_vs_region.png" && test -f "$OUT/colon_polyp_blue/visibility.png"
/usr/bin/python3 scripts/main_job_answer.py "$OUT" "${LIGHTS[@]}" > /dev/null
echo "== one beta as a Blender scene with point cloud, volume and a Cycles render"
blender -b blend_scenes/flat_tissue.blend --python-exit-code 1 --python scripts/main_job_scene.py -- \
  --out "$OUT" --beta 30 --store 100000 2>&1 | grep -v "^Fra:" || true
test -f "$OUT/render_beta30.png"
echo "== done in $(( $(date +%s) - start )) s: $OUT/report.md"
ls "$OUT"
