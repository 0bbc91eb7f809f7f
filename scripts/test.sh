#!/usr/bin/env bash
# The project's test command (README "Test"): installs the models if they
# are missing, checks the model converter on real pictures, then formatting,
# lints and every Rust test, unit and end-to-end (the e2e tests start the
# real `humem` binary and run the real models).
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== models (scripts/setup-models.sh)"
scripts/setup-models.sh
echo "== model tools tests"
models/.venv/bin/python tools/test_efficientnet_to_onnx.py models
models/.venv/bin/python tools/test_make_tiny_yolo.py
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked
