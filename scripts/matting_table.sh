#!/usr/bin/env bash
# Issue 42's figures: the pipeline without a matte, the depth split refined by `stages::matting`
# against the split as it comes and against the exact matte, on the report bench seeds 4 and 5
# (seed 3 tuned the constants) and on the Mitsuba ground truth, linear and 8-bit inputs.
# Writes docs/matting/table.md (the "Edges without a matte" sections of each report.md).
# Usage: scripts/matting_table.sh [SHARED_DIR]   (default ../shared; release build first)
set -euo pipefail
cd "$(dirname "$0")/.."
shared=${1:-${DRBOKEH_SHARED:-../shared}}
bin=./target/release/drbokeh
out=out/matting
mkdir -p "$out" docs/matting
common=(bench --methods pipeline --repeats 1 --crops 0 --inputs linear,srgb8)
{
    echo "# Edges without a matte: measured by scripts/matting_table.sh"
    echo
    echo "Generated; do not edit. Rows: the pipeline with the realistic depth map, with the exact matte, without one"
    echo "(refined, the default) and without one unrefined (\`[segment] refine = \"off\"\`)."
    for seed in 4 5; do
        "$bin" "${common[@]}" --spp 256 --scenes 20 --size 128x128 --seed "$seed" --out "$out/seed$seed" > /dev/null
        echo
        echo "## Bench seed $seed (20 scenes, 128x128)"
        sed -n '/^### Edges without a matte/,$p' "$out/seed$seed/report.md" | tail -n +2
    done
    "$bin" "${common[@]}" --groundtruth "$shared/groundtruth" --out "$out/groundtruth" > /dev/null
    echo
    echo "## Mitsuba ground truth (\`$shared/groundtruth\`)"
    sed -n '/^### Edges without a matte/,$p' "$out/groundtruth/report.md" | tail -n +2
} > docs/matting/table.md
echo "wrote docs/matting/table.md"
