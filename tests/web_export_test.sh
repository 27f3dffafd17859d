#!/usr/bin/env bash
# s2r export web in a real browser (CTest: tests_web_export, labels web and
# data): the rig bunny and the RealSense bear reconstructed, exported, opened
# in Debian's Chromium (headless, software WebGL through SwiftShader, driven
# by playwright-core from tools/node) from a static server on loopback at a
# pose 8-12 deg from an input camera; the first frame compared with
# `s2r render --pose` at the same pose: PSNR >= 30 dB, no console error, no
# exception, no failed request. Also: an export into a non-empty folder, and
# of a model without camera images, are clear errors that write nothing.
# Exit 77 (skipped, with the reason) where Chromium, the npm packages or the
# data are missing.
set -euo pipefail
s2r=$(readlink -f "${1:?usage: web_export_test.sh BUILD/app/s2r}")
here=$(cd "$(dirname "$0")/.." && pwd)
data=${S2R_DATA:-$here/../shared/data}
skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }
quiet() { "$@" >"$tmp/last.log" 2>&1 || fail "$*: $(tail -5 "$tmp/last.log")"; }
[ -x /usr/bin/chromium ] || skip "Chromium not installed (scripts/setup installs Debian's chromium)"
command -v node >/dev/null || skip "node not installed"
[ -d "$here/tools/node/node_modules/playwright-core" ] || skip "playwright-core not installed (scripts/setup: npm ci --prefix tools/node)"
[ -f "$data/stanford_bunny/bun_zipper.ply" ] || skip "$data/stanford_bunny not found (set S2R_DATA)"
[ -d "$data/realsense_d435_bear/bear" ] || skip "$data/realsense_d435_bear/bear not found (set S2R_DATA)"
tmp=$(mktemp -d /tmp/s2r_web.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
cd "$tmp"

# A view file: input camera CAM of the export turned DEG about the world's z
# axis through the bounds' centre (pinhole, the camera's own intrinsics).
make_view() {
  python3 - "$@" <<'EOF'
import json, math, sys
h = json.load(open(sys.argv[1])); c = h['cameras'][int(sys.argv[2])]; b = h['bounds']
t = [(b['min'][i] + b['max'][i]) / 2 for i in range(3)]
a = math.radians(float(sys.argv[3]))
rz = lambda v: [v[0] * math.cos(a) - v[1] * math.sin(a), v[0] * math.sin(a) + v[1] * math.cos(a), v[2]]
eye = [t[i] + rz([c['centre'][j] - t[j] for j in range(3)])[i] for i in range(3)]
R = [rz(c['right']), rz(c['down']), rz(c['fwd'])]
m = [R[0][0], R[1][0], R[2][0], eye[0], R[0][1], R[1][1], R[2][1], eye[1], R[0][2], R[1][2], R[2][2], eye[2], 0, 0, 0, 1]
K = c['K']
json.dump({"format": "s2r.view", "version": 1,
           "intrinsics": {"width": K['width'], "height": K['height'], "fx": K['fx'], "fy": K['fy'], "cx": K['cx'], "cy": K['cy'],
                          "dist": [0, 0, 0, 0, 0]},
           "world_from_camera": m}, open(sys.argv[4], 'w'))
EOF
}

# The interactive part (orbit, pan, zoom, another camera: about 15 s of
# software rendering each time) runs for the first export only.
interactive=1
check() {  # NAME MODEL CAMERA DEGREES [MIN_PSNR [EXPORT ARGS...]]
  local name=$1 model=$2 min=${5:-30} interact=$interactive
  interactive=0
  "$s2r" -q export web "$model" --out "$name-web" "${@:6}" >"$name-export.log" 2>&1 || fail "$name export: $(cat "$name-export.log")"
  make_view "$name-web/model.json" "$3" "$4" "$name-view.json"
  quiet "$s2r" render "$model" --pose "$name-view.json" --out "$name-render.png"
  local out code=0
  out=$(node "$here/tools/node/web_check.mjs" --dir "$name-web" --view "$name-view.json" --ref "$name-render.png" \
    --out "$name-browser.png" --min-psnr "$min" --interact $interact) || code=$?
  echo "$name: $out"
  echo "$name: payload $(du -sb "$name-web" | cut -f1) bytes"
  [ $code -ne 2 ] || skip "Chromium did not start: $out"
  [ $code -eq 0 ] || fail "$name: the browser's frame against s2r render: $out"
}

quiet "$s2r" synth --scene bunny --views 24 --seed 7 --out bunny
quiet "$s2r" reconstruct bunny --out bunny-model --holdout 5,17
check bunny bunny-model 0 12

quiet "$s2r" import realsense "$data/realsense_d435_bear/bear" --out bear
quiet "$s2r" calibrate markers bear --out bear-cal.json
quiet "$s2r" register bear --calibration bear-cal.json --out bear-reg
quiet "$s2r" reconstruct bear --poses bear-reg/poses.json --calibration bear-cal.json --holdout 3 --out bear-model
check bear bear-model 2 8

# A payload budget: the camera images reduced to fit, the view still drawn
# (against s2r render from the full images: a looser bound; measured 32.3 dB
# with the images reduced to 1/3, 5.8 MB of 51.6 MB).
check bunny-budget bunny-model 0 12 24 --budget-mib 8
images=$(python3 -c "import json; h=json.load(open('bunny-budget-web/model.json')); print(sum(p['bytes'] for p in h['payloads'] if p['name'] in ('colour', 'distance')))")
[ "$images" -le $((8 * 1048576)) ] || fail "the camera images take $images bytes, over the 8-MiB budget"
grep -q '"camera_image_reduction": [2-9]' bunny-budget-web/report.json || fail "no reduction reported: $(cat bunny-budget-web/report.json)"

# Bad input: nothing written.
mkdir full && echo mine >full/keep.txt
if "$s2r" -q export web bunny-model --out full >err.log 2>&1; then fail "export into a non-empty folder succeeded"; fi
grep -q "not empty" err.log || fail "non-empty folder: $(cat err.log)"
[ "$(ls full)" = keep.txt ] || fail "the non-empty folder was changed"
quiet "$s2r" reconstruct bunny --out bare --no-textures
if "$s2r" -q export web bare --out bare-web >err.log 2>&1; then fail "a model without camera images exported"; fi
grep -q "no camera images" err.log || fail "no textures: $(cat err.log)"
[ ! -e bare-web ] || fail "bare-web was written"
ls -a | grep -q partial && fail "a temporary folder was left behind"
echo "web export: ok"
