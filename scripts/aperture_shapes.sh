#!/usr/bin/env bash
# Regenerates docs/aperture_shapes.png (guide, *Aperture shapes*): the bundled scene at night
# (string lights 6-20 times brighter than white, the linear photo), focus on the flower, the
# lights behind it rendered through ten apertures: the disc, 6 blades, 5 blades with a vertex
# up, 7 rounded blades, an anamorphic disc, a star-shaped image (drawn here), a bright rim
# (--bubble), coloured fringes (--chromatic) and optical vignetting (--cat-eye) on the disc and
# on 6 blades. Needs the test .venv (OpenCV).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q --bin drbokeh --example make_scene
mkdir -p out/aperture
./target/release/examples/make_scene out/night 480 320 night > /dev/null
.venv/bin/python - <<'PY'
import math, cv2, numpy as np
n = 128
pts = []
for k in range(10):
    r = 1.0 if k % 2 == 0 else 0.45
    t = math.pi / 2 + math.pi * k / 5
    pts.append(((r * math.cos(t) + 1) / 2 * n * 16, (1 - r * math.sin(t)) / 2 * n * 16))
img = np.zeros((n, n), np.uint8)
cv2.fillPoly(img, [np.array(pts, np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
cv2.imwrite("out/aperture/star.png", img)
PY
s=(out/night/image.exr --depth out/night/depth.exr --matte out/night/matte.png --blur 40 --focus 1)
names=()
render() {
    local name=$1; shift
    ./target/release/drbokeh render "${s[@]}" "$@" -o "out/aperture/$name.png"
    names+=("$name")
}
render "disc" --aperture disc
render "blades:6" --aperture blades:6
render "blades:5,rotation=90" --aperture blades:5,rotation=90
render "blades:7,curvature=0.5" --aperture blades:7,curvature=0.5
render "disc --anamorphic 1.6" --anamorphic 1.6
render "image:star.png" --aperture image:out/aperture/star.png
render "disc --bubble 0.6" --bubble 0.6
render "disc --chromatic 0.1" --chromatic 0.1
render "disc --cat-eye 1" --cat-eye 1
render "blades:6 --cat-eye 1" --aperture blades:6 --cat-eye 1
.venv/bin/python - "${names[@]}" <<'PY'
import sys, cv2, numpy as np
tiles = []
for name in sys.argv[1:]:
    im = cv2.imread(f"out/aperture/{name}.png")[:170]  # the lights' band, above the flower
    cv2.putText(im, name, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    tiles.append(im)
rows = [cv2.hconcat(tiles[i:i + 2]) for i in range(0, len(tiles), 2)]
out = cv2.vconcat(rows)
cv2.imwrite("docs/aperture_shapes.png", cv2.resize(out, (out.shape[1] * 3 // 4, out.shape[0] * 3 // 4), interpolation=cv2.INTER_AREA))
PY
echo "wrote docs/aperture_shapes.png"
