#!/usr/bin/env bash
# The service with its embedded defaults (README "Run it"): installs the
# Debian packages the build needs and the default models if they are
# missing, then serves gRPC on 127.0.0.1:50051 with the keyframe store in
# ./data. Extra arguments go to `humem serve`.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup-system.sh run
scripts/setup-models.sh
# The service alone (`--no-default-features`: without the evaluation harness).
exec cargo run --release --locked -p humem --no-default-features -- serve "$@"
