#!/usr/bin/env bash
# The results page (docs/results.md) and the README's results table: `humem
# eval` with the shipped defaults (method Full against the ORB bag-of-words
# baseline, at most 100 evenly spaced queries of each kind) on every
# development data set, each run's JSON kept in OUT_DIR, then
# tools/results_page.py writes the page with the date, the machine, the
# commit and the command beside the figures, and replaces the table between
# the README's results markers.
#
#   scripts/results.sh [DATASETS_DIR] [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
datasets=${1:-../shared/datasets}
out=${2:-eval-results/shipped}
[ -d "$datasets" ] || { echo "no data sets at $datasets" >&2; exit 1; }

scripts/setup-models.sh
# The commit the binary is built from, taken before the build.
commit=$(git rev-parse --short=12 HEAD)
git diff --quiet HEAD -- || commit="$commit (with uncommitted changes)"
cargo build --release --locked --bin humem
humem=target/release/humem
mkdir -p "$out"

runs=()
run() { # name dataset-dir
    local name=$1 dir=$2
    echo "== $name"
    local start=$SECONDS
    "$humem" eval --dataset "$dir" --json "$out/$name.json" --report "$out/$name" >/dev/null
    # The command as a reader would type it, beside the figures.
    printf '%s\n' "humem eval --dataset \$DATASETS/${dir#"$datasets"/}" >"$out/$name.command"
    echo "   $((SECONDS - start)) s"
    runs+=("$out/$name.json")
}

run corridor "$datasets/corridor"
run gardens-daynight "$datasets/gardens-daynight"
run rtabmap-loop "$datasets/rtabmap-loop"
run town-dev-loop "$datasets/town-dev/loop"
for condition in deep_night dense_fog rain_fog sunset_glare; do
    run "town-dev-$condition" "$datasets/town-dev/$condition"
done

python3 tools/results_page.py --readme README.md --page docs/results.md --commit "$commit" "${runs[@]}"
echo "== docs/results.md and the README's table written from ${#runs[@]} runs in $out"
