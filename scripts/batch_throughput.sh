#!/usr/bin/env bash
# Batch throughput: N copies of a generated photo (default 100 photos of 1680 x 1260, 2.1 MP,
# with an EXR depth map and a PNG matte) through `drbokeh batch --jobs auto` (and any extra
# flags). Prints images per minute, wall time and CPU use (user + system over wall, out of
# 100% per core), from GNU time.
#
#   scripts/batch_throughput.sh [COUNT [WIDTH HEIGHT [extra drbokeh batch flags...]]]
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-100}; w=${2:-1680}; h=${3:-1260}; shift $(( $# < 3 ? $# : 3 ))
scene=out/batch-scene-${w}x${h}
in=out/batch-in-${n}-${w}x${h}
res=out/batch-out-${n}-${w}x${h}
cargo build --release --quiet --bin drbokeh --example make_scene
[ -f "$scene/image.png" ] || ./target/release/examples/make_scene "$scene" "$w" "$h" > /dev/null
if [ ! -d "$in" ]; then
    mkdir -p "$in"
    for i in $(seq -w 1 "$n"); do
        # Hard links: one copy of the data, N distinct inputs for the batch.
        ln "$scene/image.png" "$in/p$i.png"
        ln "$scene/depth.exr" "$in/p$i.depth.exr"
        ln "$scene/matte.png" "$in/p$i.matte.png"
    done
fi
rm -rf "$res"
/usr/bin/time -f "%e %U %S %P %M" -o "$res.time" ./target/release/drbokeh batch "$in" -o "$res" --focus 1 --blur 32 --force "$@" > /dev/null
read -r wall user sys pct kb < "$res.time"
ok=$(python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print(sum(1 for i in r.get('items', []) if i.get('status') == 'ok'))" "$res/drbokeh-batch.json")
echo "$ok of $n images of ${w}x${h} in ${wall} s: $(awk "BEGIN {printf \"%.1f\", $ok * 60 / $wall}") images/minute"
echo "CPU ${pct} of $(nproc) cores x 100% (user ${user} s, system ${sys} s), peak RSS $((kb / 1024)) MB"
