#!/usr/bin/env bash
# The project's test command (README "Test"): installs the Debian packages
# and the models if they are missing, checks the model converter on real
# pictures and the int8 models against the fp32 ones, then each crate's
# module graph (tools/check_module_graph.py), unused dependencies (cargo
# machete, installed from crates.io if missing), formatting, lints
# and every Rust test, unit and end-to-end (the e2e tests start the
# real `humem` binary and run the real models), then the C++ and the Python
# clients' tests against that binary, and the deployment files checked with the real
# Prometheus, promtool and systemd-analyze.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== system packages (scripts/setup-system.sh test)"
scripts/setup-system.sh test
echo "== models (scripts/setup-models.sh)"
scripts/setup-models.sh
echo "== model tools tests"
models/.venv/bin/python tools/test_efficientnet_to_onnx.py models
models/.venv/bin/python tools/test_quantize_models.py models
models/.venv/bin/python tools/test_make_tiny_yolo.py
models/.venv/bin/python tools/test_docs_links.py
echo "== module graph (no import circles or upward imports; files and functions within size)"
python3 tools/test_check_module_graph.py
python3 tools/check_module_graph.py
echo "== unused dependencies (cargo machete)"
command -v cargo-machete >/dev/null || cargo install cargo-machete --locked --version 0.9.2
cargo machete
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked
echo "== the compressed scan with each slower code kernel this CPU runs"
for kernel in avx2 portable; do
    HUMEM_CODE_KERNEL=$kernel cargo test --locked -p humem-core --lib
done
echo "== client-cpp (scripts/test-client-cpp.sh)"
HUMEM_BIN=target/debug/humem scripts/test-client-cpp.sh
echo "== client-python (scripts/test-client-python.sh)"
HUMEM_BIN=target/debug/humem scripts/test-client-python.sh
echo "== deployment checks (scripts/check-deploy.sh)"
HUMEM_BIN=target/debug/humem scripts/check-deploy.sh
