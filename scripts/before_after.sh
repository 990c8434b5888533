#!/usr/bin/env bash
# Regenerates docs/before_after.png (README): the bundled example's input, focus on the flower,
# focus on the wall, side by side (default profile, --blur 24). Needs the test .venv (OpenCV).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q
mkdir -p out
s=(examples/scene/image.png --depth examples/scene/depth.exr --matte examples/scene/matte.png --blur 24)
./target/release/drbokeh render "${s[@]}" --focus 1 -o out/ba_flower.png
./target/release/drbokeh render "${s[@]}" --focus 0 -o out/ba_wall.png
.venv/bin/python - <<'PY'
import cv2
imgs = [cv2.imread(p) for p in ("examples/scene/image.png", "out/ba_flower.png", "out/ba_wall.png")]
cv2.imwrite("docs/before_after.png", cv2.hconcat(imgs))
PY
