#!/usr/bin/env bash
# The main job: set up a fresh Debian 12 machine, build, then run the paper's
# experiment (the endoscope tilt beta swept from 0 to 55 deg) on
# blend_scenes/flat_tissue.blend inside Blender, and write out/main_job/:
# sweep CSV + JSON, plots, report.md, and a .blend + Cycles render for one beta.
# The sweeps render the endoscope's view per beta (views/, views_contact_sheet.png, visibility.png and the
# report's answer to "at which beta is the polyp most visible", docs/render.md). Every beta runs with a seed
# of its own, so the report's test of "varies with beta" holds its level.
# The colon is swept three times: colon_polyp.blend under white light (out/main_job/colon_polyp/) and under the
# 405 nm blue light of photodynamic diagnosis with the long-pass fluorescence filter (colon_polyp_blue/), and
# colon_polyp_spectral.blend (spectral mucosa and polyp) under white light (colon_polyp_spectral/). Each
# measures the polyp against the wall in an 8-pixel ring around it (the whole Colon region beside it:
# surround_vs_region.png) and runs each beta until the colour contrast (red/green, camera channels) has a
# standard error <= ERR (0.05), or until its cap of packets is behind its image; report.md ends with the answer
# on the colon under each light, its errors and the paper's 34 deg (scripts/main_job_answer.py).
# The colon sweeps' views come from the exitance estimate (every record near a pixel times its region's
# calibrated angular share toward the camera; docs/render.md), which agrees with the unbiased next-event
# estimate within noise. All three run every 10 deg (COLON_BETAS, SPECTRAL_BETAS, BLUE_BETAS). White light and
# the spectral tissue reach ERR at every beta from the store run and a top-up or two (caps CAP, SPECTRAL_CAP);
# blue light needs up to about 10^7 packets a beta for ERR (its long-pass image's green is dark), so it runs up
# to BLUE_CAP (1.2 x 10^7: ERR at all 6 beta, 3.4-9.0 x 10^6 packets; docs/performance.md section 22). The colon sweeps and the
# Blender scene run beside the flat sweep (their logs in OUT/), and the whole job stays within 10 minutes on 2
# idle cores.
# STORE (default 250000 fluorescent photons per beta) sets the paper's store N; BETAS the flat scene's angles;
# ERR and CAP the white colon's target; ESTIMATOR the flat scene's camera estimator (default kernel: the
# paper's estimate, as its report compares with the paper), COLON_ESTIMATOR the colon sweeps' (default exitance,
# as a sweep's own default).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT="${OUT:-out/main_job}"
STORE="${STORE:-250000}"
BETAS="${BETAS:-0:60:5}"
ERR="${ERR:-0.05}"
CAP="${CAP:-4000000}"
SPECTRAL_CAP="${SPECTRAL_CAP:-750000}"
BLUE_CAP="${BLUE_CAP:-12000000}"
BLUE_BETAS="${BLUE_BETAS:-0:60:10}"
SPECTRAL_BETAS="${SPECTRAL_BETAS:-0:60:10}"
COLON_BETAS="${COLON_BETAS:-0:60:10}"
ESTIMATOR="${ESTIMATOR:-kernel}"
COLON_ESTIMATOR="${COLON_ESTIMATOR:-exitance}"
export ENDOPHOTON_ADDON_PATH="$PWD/addon"
mkdir -p "$OUT"
start=$(date +%s)
VIEW=(--view-size 128)
if [ -n "$ESTIMATOR" ]; then VIEW+=(--estimator "$ESTIMATOR"); fi
COLON=(--betas "$COLON_BETAS" --store "$STORE" --target Polyp --background Colon --surround 8
  --target-contrast "red_green_camera:$ERR" --view-size 128 --estimator "$COLON_ESTIMATOR")
# The colon sweeps and the Blender scene run side by side with the flat sweep and with each other: a beta's
# render (numpy, mostly one core) is most of its time, so one job alone leaves a core idle. The jobs in the
# background write their progress to OUT/<name>.log.
pids=()
logs=()
trap 'kill "${pids[@]}" 2>/dev/null || true' EXIT  # a failed job stops the others
background() {  # background NAME COMMAND...: run COMMAND with its output in OUT/NAME.log
  local name="$1"
  shift
  echo "== $name (in the background: $OUT/$name.log)"
  "$@" > "$OUT/$name.log" 2>&1 &
  pids+=($!)
  logs+=("$OUT/$name.log")
}
background colon_polyp_blue /usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend \
  --out "$OUT/colon_polyp_blue" --light blue "${COLON[@]}" --betas "$BLUE_BETAS" --max-packets "$BLUE_CAP"
LIGHTS=("white=$OUT/colon_polyp" "blue=$OUT/colon_polyp_blue")
# The spectral colon (issue 35, `ep.media`: wall of colon mucosa, polyp of adenomatous polyp) is swept too,
# under white light; its answer joins the comparison. SPECTRAL=0 skips it.
if [ "${SPECTRAL:-1}" = 1 ] && [ -f blend_scenes/colon_polyp_spectral.blend ]; then
  background colon_polyp_spectral /usr/bin/python3 -m endophoton sweep \
    --blend blend_scenes/colon_polyp_spectral.blend --out "$OUT/colon_polyp_spectral" "${COLON[@]}" \
    --betas "$SPECTRAL_BETAS" --max-packets "$SPECTRAL_CAP"
  LIGHTS+=("spectral tissue, white=$OUT/colon_polyp_spectral")
fi
# one beta as a Blender scene with the point cloud, the volume and a Cycles render
background blender_scene blender -b blend_scenes/flat_tissue.blend --python-exit-code 1 \
  --python scripts/main_job_scene.py -- --out "$OUT" --beta 30 --store 100000 --section "$OUT/blender_scene.md"
echo "== beta sweep on blend_scenes/flat_tissue.blend (store $STORE per beta)"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/flat_tissue.blend --betas "$BETAS" --store "$STORE" \
  --out "$OUT" --target Polyp --background Tissue "${VIEW[@]}"
echo "== colon_polyp.blend, white light: the polyp against its surround, to a colour-contrast error of $ERR"
/usr/bin/python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend --out "$OUT/colon_polyp" "${COLON[@]}" \
  --max-packets "$CAP"
for i in "${!pids[@]}"; do
  if ! wait "${pids[$i]}"; then
    echo "main job: a background job failed: ${logs[$i]}" >&2
    tail -20 "${logs[$i]}" >&2
    exit 1
  fi
done
test -f "$OUT/colon_polyp/views_contact_sheet.png" && test -f "$OUT/colon_polyp/visibility.png"
test -f "$OUT/colon_polyp/surround_vs_region.png" && test -f "$OUT/colon_polyp_blue/visibility.png"
/usr/bin/python3 scripts/main_job_answer.py "$OUT" "${LIGHTS[@]}" --append "$OUT/blender_scene.md" > /dev/null
grep "^main job scene" "$OUT/blender_scene.log" || true
test -f "$OUT/render_beta30.png"
echo "== done in $(( $(date +%s) - start )) s: $OUT/report.md"
ls "$OUT"
