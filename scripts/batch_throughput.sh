#!/usr/bin/env bash
# Batch throughput (issue 43): N copies of a generated photo (default 100 photos of 1680 x 1260,
# 2.1 MP, with an EXR depth map and a PNG matte), K 32, focus 1, through
#   1. `drbokeh batch --jobs auto` (and any extra flags), and
#   2. the same renders as independent processes, `drbokeh render --threads 1` through
#      `xargs -P CORES` (a shell loop on every core; LOOP=0 skips it).
# Prints images per minute, wall time, CPU use (user + system over wall, out of 100% per core)
# and peak RSS (of the batch; of the largest single render for the loop), then the batch's
# share of the loop's throughput; the batch's outputs are compared with the loop's
# (byte-identical).
#
#   scripts/batch_throughput.sh [COUNT [WIDTH HEIGHT [extra drbokeh batch flags...]]]
#
# BIN=path/to/drbokeh and MAKE_SCENE=path/to/make_scene use those binaries (no cargo build;
# for a machine without cargo); WORK=DIR puts the photos and outputs there (default out/).
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-100}; w=${2:-1680}; h=${3:-1260}; shift $(( $# < 3 ? $# : 3 ))
work=${WORK:-out}
if [ -z "${BIN:-}" ]; then
    cargo build --release --quiet --bin drbokeh --example make_scene
    BIN=./target/release/drbokeh MAKE_SCENE=./target/release/examples/make_scene
fi
cores=$(nproc)
scene=$work/batch-scene-${w}x${h}
in=$work/batch-in-${n}-${w}x${h}
res=$work/batch-out-${n}-${w}x${h}
loop=$work/batch-loop-${n}-${w}x${h}
[ -f "$scene/image.png" ] || "$MAKE_SCENE" "$scene" "$w" "$h" > /dev/null
if [ ! -d "$in" ]; then
    mkdir -p "$in"
    for i in $(seq -w 1 "$n"); do
        # Hard links: one copy of the data, N distinct inputs for the batch.
        ln "$scene/image.png" "$in/p$i.png"
        ln "$scene/depth.exr" "$in/p$i.depth.exr"
        ln "$scene/matte.png" "$in/p$i.matte.png"
    done
fi

# Runs a command; prints "wall user sys peak_kb exit" (the peak is the largest of the command
# and its descendants, each counted alone).
measure() {
    python3 - "$@" <<'PY'
import os, subprocess, sys, time
t = time.perf_counter()
p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)
_, status, ru = os.wait4(p.pid, 0)
print(f"{time.perf_counter() - t:.3f} {ru.ru_utime:.2f} {ru.ru_stime:.2f} {ru.ru_maxrss} {os.waitstatus_to_exitcode(status)}")
PY
}
# Prints one result line: images, wall, user, sys, peak KiB, label.
report() {
    awk -v ok="$1" -v n="$n" -v size="${w}x${h}" -v wall="$2" -v u="$3" -v s="$4" -v kb="$5" -v cores="$cores" -v what="$6" 'BEGIN {
        printf "%s: %d of %d images of %s in %.2f s: %.1f images/minute\n", what, ok, n, size, wall, ok * 60 / wall
        printf "  CPU %d%% of %d cores x 100%% (user %.1f s, system %.1f s), peak RSS %d MB\n", (u + s) * 100 / wall, cores, u, s, kb / 1024
    }'
}

rm -rf "$res"
read -r wall user sys kb rc < <(measure "$BIN" batch "$in" -o "$res" --focus 1 --blur 32 --force "$@" 2> "$res.log")
[ "$rc" -eq 0 ] || { tail "$res.log" >&2; echo "drbokeh batch exited $rc" >&2; exit 1; }
ok=$(python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print(sum(1 for i in r.get('items', []) if i.get('status') == 'ok'))" "$res/drbokeh-batch.json")
sched=$(python3 -c "import json,sys; t=json.load(open(sys.argv[1])).get('threads_per_image', []); print(f'{len(t)} in flight, threads {sorted(set(t), reverse=True)}' if t else 'a build that does not report its schedule')" "$res/drbokeh-batch.json")
report "$ok" "$wall" "$user" "$sys" "$kb" "batch --jobs auto $* ($sched)"
batch_ipm=$(awk "BEGIN {print $ok * 60 / $wall}")

if [ "${LOOP:-1}" != 0 ]; then
    rm -rf "$loop"; mkdir -p "$loop"
    list=$work/batch-list-${n}-${w}x${h}
    for f in "$in"/p*.png; do
        [[ $f == *.matte.png ]] && continue
        s=$(basename "$f" .png)
        printf '%s\n' "$f --depth $in/$s.depth.exr --matte $in/$s.matte.png -o $loop/${s}_bokeh.png"
    done > "$list"
    read -r wall user sys kb rc < <(measure xargs -P "$cores" -L 1 -a "$list" "$BIN" render --focus 1 --blur 32 --threads 1 2> "$loop.log")
    [ "$rc" -eq 0 ] || { echo "the xargs loop exited $rc" >&2; exit 1; }
    lok=$(find "$loop" -name '*_bokeh.png' | wc -l)
    report "$lok" "$wall" "$user" "$sys" "$kb" "xargs -P $cores drbokeh render --threads 1"
    loop_ipm=$(awk "BEGIN {print $lok * 60 / $wall}")
    awk -v b="$batch_ipm" -v l="$loop_ipm" 'BEGIN {printf "batch / loop: %.0f%%\n", 100 * b / l}'
    same=$(for f in "$loop"/*_bokeh.png; do cmp -s "$f" "$res/$(basename "$f")" && echo y || echo n; done | sort | uniq -c | tr '\n' ' ')
    echo "outputs byte-identical (y) or not (n): $same"
fi
