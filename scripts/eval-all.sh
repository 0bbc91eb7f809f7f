#!/usr/bin/env bash
# The published evaluation (docs/evaluation.md, "Results"): `humem eval` with the ablation
# and the ORB bag-of-words baseline on every data set of ../shared/datasets,
# the B15/D80 and B35/D80 degradations on corridor, and town-dev's pairs
# again with ground-truth objects. Writes one report folder per run and a
# combined Markdown table, eval-results/results.md (and summary.md: SCAL, Full
# and the baseline only, the table of docs/evaluation.md).
#
#   scripts/eval-all.sh [DATASETS_DIR] [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
datasets=${1:-../shared/datasets}
out=${2:-eval-results}
[ -d "$datasets" ] || { echo "no data sets at $datasets" >&2; exit 1; }

scripts/setup-models.sh
cargo build --release --locked --bin humem
humem=target/release/humem
mkdir -p "$out"

runs=()
run() { # name dataset-dir extra-args...
    local name=$1 dir=$2
    shift 2
    runs+=("$out/$name.json")
    echo "== $name"
    "$humem" eval --dataset "$dir" --ablation --json "$out/$name.json" \
        --report "$out/$name" "$@"
}

run corridor "$datasets/corridor" --degrade B15/D80 --degrade B35/D80
run gardens-daynight "$datasets/gardens-daynight"
run rtabmap-loop "$datasets/rtabmap-loop"
run town-dev-loop "$datasets/town-dev/loop"
for condition in deep_night dense_fog rain_fog sunset_glare; do
    run "town-dev-$condition" "$datasets/town-dev/$condition"
    run "town-dev-$condition-annotated" "$datasets/town-dev/$condition" --objects annotations
done

python3 tools/eval_table.py "${runs[@]}" > "$out/results.md"
python3 tools/eval_table.py --methods SCAL,Full,ORB-BoW "${runs[@]}" > "$out/summary.md"
echo "== every number in $out/results.md; SCAL, Full and ORB-BoW in $out/summary.md"
cat "$out/summary.md"
