#!/usr/bin/env bash
# End-to-end timing of `drbokeh render` on a generated photo (default 4032 x 3024, 12.2 MP):
# decode PNG + EXR depth + PNG matte, segmentation from the matte, depth filling, Telea
# inpainting, the render (largest CoC radius 64 px: focus on the subject, K = 64), 8-bit PNG
# encode. Prints each run's wall time and peak RSS, the median, and the per-stage times of
# the last run.
#
#   scripts/e2e_timing.sh [WIDTH HEIGHT [RUNS [extra drbokeh flags...]]]
set -euo pipefail
cd "$(dirname "$0")/.."
w=${1:-4032}; h=${2:-3024}; runs=${3:-3}; shift $(( $# < 3 ? $# : 3 ))
dir=out/e2e-${w}x${h}
cargo build --release --quiet --bin drbokeh --example make_scene
[ -f "$dir/image.png" ] || ./target/release/examples/make_scene "$dir" "$w" "$h" > /dev/null
times=()
for i in $(seq "$runs"); do
    /usr/bin/time -f "%e %M" -o "$dir/time.txt" ./target/release/drbokeh render "$dir/image.png" \
        --depth "$dir/depth.exr" --matte "$dir/matte.png" --focus 1 --blur 64 -o "$dir/bokeh.png" --json "$@" > "$dir/report.json"
    read -r t kb < "$dir/time.txt"
    echo "run $i: ${t} s wall, peak RSS $((kb / 1024)) MB ($(( kb * 1024 / (w * h) )) bytes/pixel)"
    times+=("$t")
done
median=$(printf '%s\n' "${times[@]}" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
echo "median of $runs: ${median} s  (${w}x${h}, $(awk "BEGIN {printf \"%.1f\", $w*$h/1e6}") MP, $(nproc) cores)"
python3 - "$dir/report.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
for s in r.get("stages", []):
    print(f"  {s.get('name','?'):12} {s.get('ms', 0):8.0f} ms  {s.get('status', '')}")
PY
