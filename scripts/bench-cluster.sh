#!/usr/bin/env bash
# Cluster mode on this machine, in one run: a 3-node NATS JetStream cluster
# (Debian's nats-server) and 3 HuMem replicas on loopback, then
#   1. `humem bench cluster`: replica lag under ROBOTS x RATE inserts, and
#      query throughput with 1, 2 and 3 replicas;
#   2. `humem bench cluster --failover`, twice: writers on every replica
#      while one replica, then the NATS node leading the stream, is killed
#      (SIGKILL) and started again; the longest wait for an acknowledgement
#      (the failover time) and the acknowledged writes lost (must be 0).
#
#   scripts/bench-cluster.sh [--robots N] [--rate HZ] [--duration S] [--dim D]
#
# HUMEM_BIN names the binary (default: target/release/humem, built if
# missing). Every process is stopped at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
robots=8 rate=10 duration=20 dim=256
while [ $# -gt 0 ]; do
    case $1 in
        --robots) robots=$2; shift 2 ;;
        --rate) rate=$2; shift 2 ;;
        --duration) duration=$2; shift 2 ;;
        --dim) dim=$2; shift 2 ;;
        *) echo "usage: $0 [--robots N] [--rate HZ] [--duration S] [--dim D]" >&2; exit 2 ;;
    esac
done
command -v nats-server >/dev/null || { echo "nats-server is missing: scripts/setup-system.sh test" >&2; exit 1; }
bin=${HUMEM_BIN:-target/release/humem}
if [ ! -x "$bin" ]; then
    cargo build --release --locked -p humem --bin humem
fi
tmp=$(mktemp -d)
declare -A nats_pid humem_pid
cleanup() {
    for p in "${nats_pid[@]}" "${humem_pid[@]}"; do kill -9 "$p" 2>/dev/null || true; done
    rm -rf "$tmp"
}
trap cleanup EXIT

base=$((20000 + RANDOM % 20000))
routes="nats://127.0.0.1:$((base + 10)),nats://127.0.0.1:$((base + 11)),nats://127.0.0.1:$((base + 12))"
urls="[\"nats://127.0.0.1:$base\",\"nats://127.0.0.1:$((base + 1))\",\"nats://127.0.0.1:$((base + 2))\"]"

start_nats() { # index
    local i=$1
    nats-server -a 127.0.0.1 -p $((base + i)) -m $((base + 20 + i)) -n "n$i" -js -sd "$tmp/nats-$i" \
        --cluster_name bench --cluster "nats://127.0.0.1:$((base + 10 + i))" --routes "$routes" \
        >"$tmp/nats-$i.log" 2>&1 &
    nats_pid[$i]=$!
    disown  # killed on purpose below: no job-control notices
}

start_humem() { # index port
    local i=$1 port=$2
    : >"$tmp/humem-$i.out"
    env -u HUMEM_CONFIG RUST_LOG=warn HUMEM_PERCEPTION__ENABLED=false HUMEM_METRICS__ENABLED=false \
        HUMEM_CLUSTER__ENABLED=true HUMEM_CLUSTER__NATS_URLS="$urls" HUMEM_CLUSTER__REPLICA_NAME="r$i" \
        "$bin" serve --listen "127.0.0.1:$port" --data-dir "$tmp/humem-$i" >"$tmp/humem-$i.out" 2>"$tmp/humem-$i.err" &
    humem_pid[$i]=$!
    disown
    for _ in $(seq 600); do
        grep -q '^humem listening on ' "$tmp/humem-$i.out" && return 0
        sleep 0.1
    done
    cat "$tmp/humem-$i.err" >&2
    exit 1
}

# The NATS node leading the stream, from the monitoring endpoints.
stream_leader() {
    local i
    for i in 0 1 2; do
        curl -s "http://127.0.0.1:$((base + 20 + i))/jsz?streams=true" 2>/dev/null \
            | python3 -c 'import json,sys
d=json.load(sys.stdin)
for a in d.get("account_details",[]):
    for s in a.get("stream_detail",[]):
        if s["name"]=="HUMEM_WRITES": print(s["cluster"]["leader"]); sys.exit()' 2>/dev/null && return 0
    done
}

for i in 0 1 2; do start_nats "$i"; done
ports=($((base + 30)) $((base + 31)) $((base + 32)))
for i in 0 1 2; do start_humem "$i" "${ports[$i]}"; done
replicas="http://127.0.0.1:${ports[0]},http://127.0.0.1:${ports[1]},http://127.0.0.1:${ports[2]}"

echo "== lag and throughput (3 NATS nodes, stream with 3 copies, 3 replicas; $(nproc) cores)"
"$bin" bench cluster --replicas "$replicas" --robots "$robots" --rate "$rate" --duration "$duration" --dim "$dim"

echo
echo "== failover 1: a HuMem replica (SIGKILL on r2 at t=5 s, started again at t=10 s)"
"$bin" bench cluster --replicas "$replicas" --dim "$dim" --failover 15 &
bench=$!
sleep 5
kill -9 "${humem_pid[2]}"
sleep 5
start_humem 2 "${ports[2]}"
wait "$bench"

echo
echo "== failover 2: the NATS node leading the stream (SIGKILL at t=5 s, started again at t=10 s)"
"$bin" bench cluster --replicas "$replicas" --dim "$dim" --failover 15 &
bench=$!
sleep 5
leader=$(stream_leader || true)
echo "stream leader: ${leader:-unknown (killing n0)}"
leader=${leader#n}
leader=${leader:-0}
kill -9 "${nats_pid[$leader]}"
sleep 5
start_nats "$leader"
wait "$bench"
