#!/usr/bin/env bash
# What TLS and tokens cost per call: the same `humem load` (synthetic
# features, light enough that nothing queues) against three servers started
# here one after the other, in one run: plaintext, TLS, and TLS with tokens
# (a fresh token per run). Prints p50 and p95 of Insert and Query, and each
# against plaintext.
#
#   scripts/bench-security.sh [--robots N] [--rate HZ] [--duration S] [--dim D]
#
# HUMEM_BIN names the binary (default: target/release/humem, built if
# missing). Certificates come from scripts/make-dev-certs.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
robots=2 rate=10 duration=20 dim=512
while [ $# -gt 0 ]; do
    case $1 in
        --robots) robots=$2; shift 2 ;;
        --rate) rate=$2; shift 2 ;;
        --duration) duration=$2; shift 2 ;;
        --dim) dim=$2; shift 2 ;;
        *) echo "usage: $0 [--robots N] [--rate HZ] [--duration S] [--dim D]" >&2; exit 2 ;;
    esac
done
bin=${HUMEM_BIN:-target/release/humem}
if [ ! -x "$bin" ]; then
    cargo build --release --locked -p humem --bin humem
fi
tmp=$(mktemp -d)
pid=""
cleanup() { [ -n "$pid" ] && kill "$pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
scripts/make-dev-certs.sh "$tmp/certs" localhost 127.0.0.1 >/dev/null

# run NAME [KEY=VALUE...]: starts a server with those settings, loads it,
# keeps the load report in $tmp/NAME.txt.
run() {
    local name=$1
    shift
    env -u HUMEM_CONFIG RUST_LOG=warn HUMEM_PERCEPTION__ENABLED=false HUMEM_METRICS__ENABLED=false "$@" \
        "$bin" serve --listen 127.0.0.1:0 --data-dir "$tmp/$name-data" >"$tmp/$name.out" 2>"$tmp/$name.err" &
    pid=$!
    for _ in $(seq 300); do
        grep -q '^humem listening on ' "$tmp/$name.out" && break
        sleep 0.1
    done
    local addr
    addr=$(sed -n 's/^humem listening on //p' "$tmp/$name.out")
    [ -n "$addr" ] || { cat "$tmp/$name.err" >&2; exit 1; }
    local args=(--server "http://$addr")
    if [ "$name" != plaintext ]; then
        args=(--server "https://127.0.0.1:${addr##*:}" --tls-ca "$tmp/certs/ca.crt")
    fi
    if [ "$name" = tls+token ]; then
        args+=(--token "$("$bin" token add --file "$tmp/tokens.json" --robot bench --role admin 2>/dev/null)")
        sleep 0.5  # the server reads the token file again within 250 ms
    fi
    "$bin" load "${args[@]}" --robots "$robots" --rate "$rate" --duration "$duration" --dim "$dim" >"$tmp/$name.txt"
    kill "$pid"
    wait "$pid" 2>/dev/null || true
    pid=""
}
tls=(HUMEM_SERVER__TLS__CERT="$tmp/certs/tls.crt" HUMEM_SERVER__TLS__KEY="$tmp/certs/tls.key")
run plaintext
run tls "${tls[@]}"
run tls+token "${tls[@]}" HUMEM_AUTH__TOKENS_FILE="$tmp/tokens.json"

# The p50 and p95 columns of a call's row in a load report.
percentiles() { awk -v call="$2" '$1 == call { print $7, $8, $4 + $5 }' "$tmp/$1.txt"; }
echo "TLS and tokens, $robots robots x $rate Hz for $duration s, $dim-d synthetic features ($("$bin" --version))"
echo "| call | setup | p50 ms | p95 ms | p50 vs plaintext | p95 vs plaintext | not ok |"
echo "| --- | --- | --- | --- | --- | --- | --- |"
for call in insert query; do
    read -r base50 base95 _ < <(percentiles plaintext "$call")
    for name in plaintext tls tls+token; do
        read -r p50 p95 bad < <(percentiles "$name" "$call")
        awk -v c="$call" -v n="$name" -v a="$p50" -v b="$p95" -v a0="$base50" -v b0="$base95" -v bad="$bad" \
            'BEGIN { printf "| %s | %s | %.2f | %.2f | %.2fx | %.2fx | %d |\n", c, n, a, b, a / a0, b / b0, bad }'
    done
done
