#!/usr/bin/env bash
# The project's test command (README "Test"): formatting, lints, then every
# test, unit and end-to-end (the e2e tests start the real `humem` binary).
# Needs only the Rust toolchain: protoc comes from a crate.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked
