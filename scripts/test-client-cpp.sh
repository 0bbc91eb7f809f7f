#!/usr/bin/env bash
# Tests the C++ client library (client-cpp/): configures and builds it
# (Release, -j2), runs its tests with ctest against the real server binary,
# runs the server tests again over TLS with a bearer token (certificates
# from scripts/make-dev-certs.sh: a CA, a server certificate for localhost,
# another CA; the token from `humem token add`), then
# installs it to a temporary prefix and builds and runs a tiny C++11
# consumer project with find_package(humem_client), proving the CMake
# package and the C++11-compatible headers.
#
# The server binary comes from HUMEM_BIN (default: target/debug/humem);
# build it first (`cargo build --locked --bin humem`).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

bin=${HUMEM_BIN:-target/debug/humem}
case "$bin" in /*) ;; *) bin="$root/$bin" ;; esac
if [ ! -x "$bin" ]; then
    echo "test-client-cpp: humem binary not found at $bin" >&2
    echo "  build it with 'cargo build --locked --bin humem', or set HUMEM_BIN" >&2
    exit 1
fi
export HUMEM_BIN="$bin"
jobs=${JOBS:-2}

echo "== client-cpp: configure and build"
cmake -S client-cpp -B client-cpp/build -DCMAKE_BUILD_TYPE=Release -DHUMEM_BIN="$bin"
cmake --build client-cpp/build -j"$jobs"

echo "== client-cpp: tests (server: $bin)"
ctest --test-dir client-cpp/build --output-on-failure -j"$jobs"

echo "== client-cpp: the server tests again, over TLS with a token"
tls=$(mktemp -d)
trap 'rm -rf "$tls"' EXIT
scripts/make-dev-certs.sh "$tls" localhost 127.0.0.1 >/dev/null
scripts/make-dev-certs.sh "$tls/other" localhost >/dev/null
cp "$tls/other/ca.crt" "$tls/other-ca.crt"
# An admin token: the suite's clients act for several robot ids.
"$bin" token add --file "$tls/tokens.json" --robot client-tests --role admin >"$tls/token" 2>/dev/null
HUMEM_TEST_TLS_DIR="$tls" client-cpp/build/tests/humem_client_server_tests

echo "== client-cpp: install and build a C++11 consumer with find_package(humem_client)"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp" "$tls"' EXIT
cmake --install client-cpp/build --prefix "$tmp/prefix"
cmake -S client-cpp/tests/consumer -B "$tmp/consumer" -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_PREFIX_PATH="$tmp/prefix"
if ! cmake --build "$tmp/consumer" --verbose -j"$jobs" >"$tmp/consumer.log" 2>&1; then
    cat "$tmp/consumer.log" >&2
    echo "test-client-cpp: the C++11 consumer did not build" >&2
    exit 1
fi
grep -q -e '-std=c++11' "$tmp/consumer.log" \
    || { cat "$tmp/consumer.log" >&2; echo "test-client-cpp: the consumer was not compiled with -std=c++11" >&2; exit 1; }
"$tmp/consumer/consumer"

# Optional: the ORB-SLAM3 harness (client-cpp/orbslam3/harness): CI cannot
# fetch ORB-SLAM3, so its driver and vocabulary trainer are built only when
# a checkout (v1.0, commit 0df83dd) and a Pangolin v0.6 prefix are given.
if [ -n "${HUMEM_ORBSLAM3_DIR:-}" ]; then
    [ -n "${HUMEM_PANGOLIN_PREFIX:-}" ] \
        || { echo "test-client-cpp: HUMEM_ORBSLAM3_DIR is set but HUMEM_PANGOLIN_PREFIX is not" >&2; exit 1; }
    echo "== client-cpp: ORB-SLAM3 harness: patch, build libORB_SLAM3 with the plugin, the driver and the vocabulary trainer"
    client-cpp/orbslam3/harness/run.sh --build-only --orbslam3 "$HUMEM_ORBSLAM3_DIR" \
        --pangolin "$HUMEM_PANGOLIN_PREFIX" --work "${HUMEM_ORBSLAM3_WORK:-$root/client-cpp/build/orbslam3-harness}"
else
    echo "== client-cpp: ORB-SLAM3 harness: skipped (set HUMEM_ORBSLAM3_DIR and HUMEM_PANGOLIN_PREFIX to build it)"
fi
echo "== client-cpp: OK"
