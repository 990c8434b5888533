#!/bin/bash
# Issue 39's many-core measurement on a lent machine (the `device` tool), from the repository
# root: `bash scripts/scaling_device.sh` with `devbin/` carried, holding this build's
# `new/drbokeh` and `new/make_scene` and the start build's `old/drbokeh` (built here: the lent
# machine has no cargo). Writes scaling-new.md, scaling-old.md and arenas.log to $OUT; the
# README's table is docs/perf/scaling-device.md, made from them.
set -o pipefail
export PYTHONUNBUFFERED=1
cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)
echo "cores $(nproc); $cpu; kernel $(uname -r)"
python3 -c "import cv2, numpy; print('cv2', cv2.__version__, 'numpy', numpy.__version__)"
W=${W:-/tmp/s}; mkdir -p "$W"
devbin/new/make_scene "$W" 4032 3024 > /dev/null || exit 1
python3 scripts/scaling.py --bin devbin/new --work "$W" --threads 1,2,4,8,16 --runs 3 \
  --label "lent device machine ($cpu, $(nproc) cores, gVisor), this build" --out "$OUT/scaling-new.md" 2>&1 | tee "$OUT/new.log"
python3 scripts/scaling.py --bin devbin/old --work "$W" --threads 1,2,4,8,16 --runs 3 --no-gaussian \
  --label "lent device machine ($cpu, $(nproc) cores, gVisor), start build ddb629f" --out "$OUT/scaling-old.md" 2>&1 | tee "$OUT/old.log"
# Peak RSS at 16 threads under glibc's malloc arena limits.
python3 - "$W" <<'PY' 2>&1 | tee "$OUT/arenas.log"
import os, subprocess, sys, time
w = sys.argv[1]
cmd = ["devbin/new/drbokeh", "render", f"{w}/image.png", "--depth", f"{w}/depth.exr", "--matte", f"{w}/matte.png",
       "--focus", "1", "--blur", "64", "-o", f"{w}/arena.png", "--threads", "16"]
# default: render's own rule (one arena per four threads); 128: one per thread (glibc's default)
for arenas in [None, "128", "8", "4", "2"]:
    env = dict(os.environ, **({"MALLOC_ARENA_MAX": arenas} if arenas else {}))
    for _ in range(2):
        t = time.perf_counter()
        p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, status, ru = os.wait4(p.pid, 0)
        print(f"MALLOC_ARENA_MAX={arenas or 'default'}: {time.perf_counter() - t:.3f} s, peak {ru.ru_maxrss / 2**20:.2f} GiB, status {status}")
PY
