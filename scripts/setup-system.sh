#!/usr/bin/env bash
# Installs the Debian packages HuMem's commands need, only those missing:
#   run   building and serving (scripts/run.sh): unzip (model setup) and CMake
#         (the turbojpeg crate builds libjpeg-turbo from source)
#   test  everything scripts/test.sh needs besides: the DejaVu fonts (the OCR
#         test's rendered text, evaluation charts), Prometheus with promtool and
#         systemd-analyze (deployment checks), gRPC C++, protobuf and GoogleTest
#         (client-cpp), the openssl command (the C++ suite's TLS
#         certificates) and nats-server (the cluster-mode tests)
# The Rust toolchain (with rustfmt and clippy) and Python 3.11 are expected on
# the machine. Installs with apt-get as root, or through passwordless sudo;
# otherwise it stops at once and prints the one command to run first.
#
#   scripts/setup-system.sh run|test
set -euo pipefail
purpose=${1:-test}
missing=()
command -v unzip >/dev/null || missing+=(unzip)
command -v cmake >/dev/null || missing+=(cmake)
if [ "$purpose" = test ]; then
    [ -f /usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf ] || missing+=(fonts-dejavu-core)
    command -v promtool >/dev/null || missing+=(prometheus)
    command -v systemd-analyze >/dev/null || missing+=(systemd)
    command -v grpc_cpp_plugin >/dev/null || missing+=(protobuf-compiler-grpc)
    command -v openssl >/dev/null || missing+=(openssl)
    command -v nats-server >/dev/null || missing+=(nats-server)
    dpkg -s libgrpc++-dev libprotobuf-dev protobuf-compiler libgtest-dev >/dev/null 2>&1 \
        || missing+=(libgrpc++-dev libprotobuf-dev protobuf-compiler libgtest-dev)
elif [ "$purpose" != run ]; then
    echo "usage: $0 run|test" >&2
    exit 2
fi
[ ${#missing[@]} -eq 0 ] && exit 0
install=(apt-get install -y --no-install-recommends "${missing[@]}")
if [ "$(id -u)" -eq 0 ]; then
    sudo=()
elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo=(sudo -n)  # passwordless sudo: never waits at a prompt
else
    # Stop at once with the one command to run first, rather than wait at a
    # password prompt or fail halfway through a build.
    echo "setup-system: missing Debian packages: ${missing[*]}" >&2
    echo "setup-system: run this first, then this command again:" >&2
    echo "    sudo apt-get update && sudo ${install[*]}" >&2
    exit 1
fi
echo "setup-system: installing ${missing[*]}"
"${sudo[@]}" apt-get update -qq
DEBIAN_FRONTEND=noninteractive "${sudo[@]}" "${install[@]}" -qq
