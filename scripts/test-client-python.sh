#!/usr/bin/env bash
# Tests the Python client (clients/python/): installs it with pip into a
# throwaway venv whose dependencies are the hash-pinned ones of models/.venv
# (scripts/setup-models.sh: grpcio, protobuf, numpy, Pillow, grpcio-tools;
# no download, pip checks the declared dependency ranges against them),
# then runs its unittest suite against the real server binary: the stubs
# regenerated from proto/ and compared, insert, query, erase, scopes, images
# through the real models, latest-wins, TLS with a token (certificates from
# openssl, the token from `humem token add`), typed errors, and the README's
# example (examples/quickstart.py).
#
# The server binary comes from HUMEM_BIN (default: target/debug/humem);
# build it first (`cargo build --locked --bin humem`).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

bin=${HUMEM_BIN:-target/debug/humem}
case "$bin" in /*) ;; *) bin="$root/$bin" ;; esac
if [ ! -x "$bin" ]; then
    echo "test-client-python: humem binary not found at $bin" >&2
    echo "  build it with 'cargo build --locked --bin humem', or set HUMEM_BIN" >&2
    exit 1
fi
python=$root/models/.venv/bin/python
[ -x "$python" ] || { echo "test-client-python: $python missing: run scripts/setup-models.sh" >&2; exit 1; }
"$python" -c 'import grpc_tools, setuptools' 2>/dev/null \
    || { echo "test-client-python: models/.venv lacks grpcio-tools or setuptools: run scripts/setup-models.sh" >&2; exit 1; }

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "== client-python: pip install ./clients/python (into a throwaway venv)"
"$python" -m venv --without-pip "$tmp/venv"
site=$("$tmp/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
"$python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])' >"$site/humem-models-venv.pth"
# Built from a copy: setuptools builds in the source folder (build/, *.egg-info).
cp -r "$root/clients/python" "$tmp/src"
rm -rf "$tmp/src/build" "$tmp/src"/*.egg-info
"$python" -m pip --disable-pip-version-check --python "$tmp/venv/bin/python" install -q \
    --no-index --no-build-isolation "$tmp/src"
"$tmp/venv/bin/python" -c 'import humem_client, sys; sys.exit(0 if "/venv/" in humem_client.__file__ else 1)' \
    || { echo "test-client-python: humem_client was not imported from the venv" >&2; exit 1; }

echo "== client-python: tests (server: $bin)"
# unittest puts the tests folder, not clients/python, first on sys.path: the
# installed package is the one under test.
# HUMEM_CLIENT_STRICT: fail, not skip, where grpcio-tools is missing.
tests=$root/clients/python/tests
if ! HUMEM_BIN="$bin" HUMEM_CLIENT_STRICT=1 GRPC_VERBOSITY=ERROR PYTHONDONTWRITEBYTECODE=1 \
    "$tmp/venv/bin/python" -m unittest discover -v -s "$tests" -t "$tests" 2>&1 | tee "$tmp/unittest.log"; then
    echo "test-client-python: tests failed" >&2
    exit 1
fi
# The plain summary line CI reads (unittest's own is "Ran N tests ... OK").
ran=$(sed -n 's/^Ran \([0-9]*\) tests\? in .*/\1/p' "$tmp/unittest.log")
skipped=$(sed -n 's/^OK (skipped=\([0-9]*\))$/\1/p' "$tmp/unittest.log")
echo "client-python: $((ran - ${skipped:-0})) passed, 0 failed${skipped:+, $skipped skipped}"
echo "== client-python: OK"
