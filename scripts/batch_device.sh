#!/bin/bash
# Issue 43's many-core batch measurement on a lent machine (the `device` tool), from the
# repository root: `bash scripts/batch_device.sh` with `out/devbin` carried, holding this
# build's `new/drbokeh` and `new/make_scene` and the start build's `old/drbokeh` (built here:
# the lent machine has no cargo). Each report is `scripts/batch_throughput.sh`'s (the batch
# beside the `xargs -P` loop of single-threaded renders); everything goes to $OUT/batch.log.
set -o pipefail
export PYTHONUNBUFFERED=1 WORK=${WORK:-/tmp/b} MAKE_SCENE=out/devbin/new/make_scene
mkdir -p "$WORK"
log=${OUT:-/tmp}/batch.log
{
    echo "cores $(nproc); $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); kernel $(uname -r)"
    grep -E 'MemTotal|MemAvailable' /proc/meminfo
} | tee "$log"
d=out/devbin
go() { echo "=== $*" | tee -a "$log"; env "$@" 2>&1 | tee -a "$log"; }
# 2.1 MP, 64 photos (the table), twice.
go BIN=$d/new/drbokeh scripts/batch_throughput.sh 64
go BIN=$d/new/drbokeh scripts/batch_throughput.sh 64
# 12.2 MP, 32 photos.
go BIN=$d/new/drbokeh scripts/batch_throughput.sh 32 4032 3024
# 12.2 MP under an 8 GB budget: three images in flight, the cores split among them.
printf '[batch]\nmemory_budget_mb = 8192\n' > "$WORK/budget.toml"
go BIN=$d/new/drbokeh LOOP=0 scripts/batch_throughput.sh 32 4032 3024 --config "$WORK/budget.toml"
[ -z "${OLD:-}" ] || go BIN=$d/old/drbokeh LOOP=0 scripts/batch_throughput.sh 64
echo "done" | tee -a "$log"
