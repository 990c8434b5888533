#!/usr/bin/env bash
# Regenerates docs/highlights_before_after.png (README, *Clipped highlights*): the bundled
# scene at night (string lights 6-20 times brighter than white, stored as an 8-bit PNG),
# focus on the flower, rendered with `--highlights off` and with the default `auto`, side by
# side after the 8-bit photo, and last the render of the unclipped linear photo (what `auto`
# aims at). Needs the test .venv (OpenCV).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q --bin drbokeh --example make_scene
mkdir -p out
./target/release/examples/make_scene out/night 480 320 night > /dev/null
s=(out/night/image.png --depth out/night/depth.exr --matte out/night/matte.png --blur 24 --focus 1)
./target/release/drbokeh render "${s[@]}" --highlights off -o out/night_off.png
./target/release/drbokeh render "${s[@]}" -o out/night_auto.png
./target/release/drbokeh render out/night/image.exr "${s[@]:1}" -o out/night_linear.png
.venv/bin/python - <<'PY'
import cv2
imgs = [cv2.imread(p) for p in ("out/night/image.png", "out/night_off.png", "out/night_auto.png", "out/night_linear.png")]
row = cv2.hconcat(imgs)
# Half size: four 480-px panels.
cv2.imwrite("docs/highlights_before_after.png", cv2.resize(row, (row.shape[1] // 2, row.shape[0] // 2), interpolation=cv2.INTER_AREA))
PY
echo "wrote docs/highlights_before_after.png"
