#!/usr/bin/env bash
# Checks the operator files in deploy/ and docker/ with the real tools:
#   1. promtool: the Prometheus configuration, the alerting rules, and their unit tests;
#   2. the Grafana dashboard's structure (ids, variables, datasource references);
#   3. the Kubernetes manifests, Grafana provisioning, compose file and systemd
#      files parse and agree with each other and with the service's configuration;
#   4. the Dockerfiles, linted offline (no Docker engine is needed);
#   5. systemd-analyze verify and security on the unit, sysusers and tmpfiles
#      into a scratch root (skipped, with a message, without systemd-analyze);
#   6. every example configuration (sidecar, Kubernetes, container) is accepted
#      by the real binary, which starts with it on its own address, answers
#      /readyz, serves TLS with a token where the configuration asks for them
#      (development certificates from scripts/make-dev-certs.sh) and refuses
#      a call without one, and stops cleanly on SIGTERM;
#   7. a live run: a real `humem serve` with the real models, driven by
#      `humem load` (synthetic and image keyframes, image queries, an
#      overload burst, a client with the wrong descriptor length), scraped
#      every second by a real Prometheus that also evaluates the alerting
#      rules; then every dashboard query and every alert-rule operand is
#      evaluated through Prometheus' HTTP API and must return data.
#
#   HUMEM_BIN=/path/to/humem scripts/check-deploy.sh     (default: target/debug/humem, built if missing)
#
# Needs promtool and prometheus (Debian: apt-get install prometheus), Python 3.11
# with PyYAML (models/.venv or python3), unzip; the models of scripts/setup-models.sh.
# CHECK_DEPLOY_VERBOSE=1 lists every passed structural check.
set -euo pipefail
BIN_GIVEN=${HUMEM_BIN:+yes}
# HUMEM_BIN relative to where the script was called from.
[[ -z $BIN_GIVEN || $HUMEM_BIN == /* ]] || HUMEM_BIN=$PWD/$HUMEM_BIN
cd "$(dirname "$0")/.."
REPO=$PWD
BIN=${HUMEM_BIN:-$REPO/target/debug/humem}
LOAD_SECONDS=${CHECK_DEPLOY_LOAD_SECONDS:-20}
# The service reads HUMEM_* settings from the environment: none of the caller's.
while read -r var; do unset "$var"; done < <(compgen -e | grep '^HUMEM_' || true)
unset RUST_LOG
# No __pycache__ in deploy/checks.
export PYTHONDONTWRITEBYTECODE=1

die() { echo "check-deploy: ERROR: $*" >&2; exit 1; }
step() { echo; echo "== $*"; }

TMP=$(mktemp -d)
PIDS=()
cleanup() {
    local pid
    for pid in "${PIDS[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
    for pid in "${PIDS[@]}"; do
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$pid" 2>/dev/null || true
        wait "$pid" 2>/dev/null || true
    done
    rm -rf "$TMP"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# --- tools --------------------------------------------------------------------------------------
command -v promtool >/dev/null && command -v prometheus >/dev/null \
    || die "promtool and prometheus are needed (Debian: apt-get install prometheus)"
step "models (scripts/setup-models.sh)"
scripts/setup-models.sh
PY=python3
YAML_PY=
for candidate in models/.venv/bin/python python3; do
    if "$candidate" -c 'import yaml' 2>/dev/null; then YAML_PY=$candidate; break; fi
done
[[ -n $YAML_PY ]] || die "PyYAML is needed to parse the manifests (models/.venv or python3)"
if [[ -z $BIN_GIVEN && ! -x $BIN ]]; then
    step "cargo build (no $BIN yet)"
    cargo build --locked --bin humem
fi
[[ -x $BIN ]] || die "no humem binary at $BIN (set HUMEM_BIN)"
echo "humem binary: $BIN ($("$BIN" --version))"

# start_humem NAME ARGS...: `humem serve ARGS...` in the background, with the
# KEY=VALUE settings of the array SERVER_ENV, its stdout in $TMP/NAME.out and
# stderr in $TMP/NAME.err; waits for "humem listening on" and sets SERVER_PID,
# SERVER_GRPC and SERVER_METRICS.
start_humem() {
    local name=$1 out=$TMP/$1.out
    shift
    env RUST_LOG="warn,ort::logging=error" "${SERVER_ENV[@]}" "$BIN" serve "$@" >"$out" 2>"$TMP/$name.err" &
    SERVER_PID=$!
    PIDS+=("$SERVER_PID")
    for _ in $(seq 600); do
        grep -q '^humem listening on ' "$out" && break
        kill -0 "$SERVER_PID" 2>/dev/null || break
        sleep 0.1
    done
    if ! grep -q '^humem listening on ' "$out"; then
        cat "$TMP/$name.err" >&2
        return 1
    fi
    SERVER_GRPC=$(sed -n 's/^humem listening on //p' "$out")
    SERVER_METRICS=$(sed -n 's/^humem metrics on //p' "$out")
}

# SIGTERM, then the exit status (0: drained and flushed).
stop_humem() {
    kill -TERM "$SERVER_PID"
    local status=0
    wait "$SERVER_PID" || status=$?
    return $status
}

# --- 1. Prometheus ------------------------------------------------------------------------------
step "promtool: configuration, rules, rule unit tests"
promtool check config deploy/prometheus/prometheus.yml
promtool check rules deploy/prometheus/rules/*.rules.yml
promtool test rules deploy/prometheus/tests/*.test.yml

# --- 2.-4. structure ----------------------------------------------------------------------------
step "Grafana dashboard structure"
$PY deploy/checks/check_dashboard.py deploy/grafana/dashboards/humem.json
step "Kubernetes, Grafana provisioning, compose, systemd files ($YAML_PY)"
$YAML_PY deploy/checks/check_manifests.py "$REPO"
step "Dockerfiles (offline lint)"
$PY deploy/checks/check_docker.py "$REPO" docker/Dockerfile docker/Dockerfile.cuda

# --- 5. systemd ---------------------------------------------------------------------------------
step "systemd unit"
if command -v systemd-analyze >/dev/null; then
    # The unit as shipped, but for ExecStart's binary, which is not installed
    # here: verify checks that it exists and is executable.
    mkdir -p "$TMP/unit"
    sed "s#^ExecStart=/usr/local/bin/humem #ExecStart=$BIN #" deploy/systemd/humem.service >"$TMP/unit/humem.service"
    changed=$(diff deploy/systemd/humem.service "$TMP/unit/humem.service" | grep -c '^>' || true)
    [[ $changed == 1 ]] || die "expected to rewrite exactly one ExecStart= line, rewrote $changed"
    # verify exits 0 on unknown keys and bad values, so any message is a failure.
    if ! out=$(systemd-analyze verify "$TMP/unit/humem.service" 2>&1) || [[ -n $out ]]; then
        echo "$out"
        die "systemd-analyze verify found problems in deploy/systemd/humem.service"
    fi
    echo "systemd-analyze verify: clean"
    if systemd-analyze security --help 2>/dev/null | grep -q -- '--offline'; then
        systemd-analyze security --offline=yes --threshold=20 "$TMP/unit/humem.service" >"$TMP/security.txt" 2>&1 \
            || { cat "$TMP/security.txt"; die "exposure above 2.0 (systemd-analyze security)"; }
        grep 'Overall exposure' "$TMP/security.txt" | sed 's/^→ /systemd-analyze security: /'
    fi
    mkdir -p "$TMP/root/etc"
    systemd-sysusers --root="$TMP/root" "$REPO/deploy/systemd/humem.sysusers.conf" >/dev/null 2>&1 \
        || die "systemd-sysusers refused deploy/systemd/humem.sysusers.conf"
    systemd-tmpfiles --root="$TMP/root" --create "$REPO/deploy/systemd/humem.tmpfiles.conf" \
        || die "systemd-tmpfiles refused deploy/systemd/humem.tmpfiles.conf"
    uid=$(awk -F: '$1 == "humem" {print $3}' "$TMP/root/etc/passwd")
    [[ -n $uid && $(stat -c %u "$TMP/root/data/humem") == "$uid" ]] \
        || die "sysusers/tmpfiles did not make /data/humem owned by humem"
    echo "sysusers + tmpfiles: user humem (uid $uid) owns /data/humem in a scratch root"
else
    echo "skipped: systemd-analyze is not installed (Debian: apt-get install systemd)"
fi

# --- 6. the example configurations, read by the real binary -------------------------------------
step "example configurations, started by the real binary"
scripts/make-dev-certs.sh "$TMP/certs" >/dev/null
for config in deploy/systemd/humem.toml deploy/kubernetes/base/humem.toml docker/humem.toml; do
    name=config-$(echo "$config" | tr / -)
    # Only the places change: ports (on the configuration's own address, so
    # that the refusal to serve a network address insecurely applies), the
    # store, the models (here in ./models), and for a configuration with
    # TLS and tokens, the certificate (scripts/make-dev-certs.sh) and the
    # token file.
    read -r host tls tokens < <($PY -c 'import sys, tomllib
c = tomllib.load(open(sys.argv[1], "rb"))
host = c.get("server", {}).get("listen", "127.0.0.1:50051").rsplit(":", 1)[0]
print(host, int("tls" in c.get("server", {})), int("tokens_file" in c.get("auth", {})))' "$config")
    SERVER_ENV=(HUMEM_SERVER__LISTEN="$host:0" HUMEM_METRICS__LISTEN=127.0.0.1:0
                HUMEM_STORE__DATA_DIR="$TMP/$name-data" HUMEM_PERCEPTION__MODELS_DIR="$REPO/models")
    [[ $tls == 1 ]] && SERVER_ENV+=(HUMEM_SERVER__TLS__CERT="$TMP/certs/tls.crt" HUMEM_SERVER__TLS__KEY="$TMP/certs/tls.key")
    [[ $tokens == 1 ]] && SERVER_ENV+=(HUMEM_AUTH__TOKENS_FILE="$TMP/$name-tokens.json")
    start_humem "$name" --config "$config" || die "humem serve refused $config (log above)"
    [[ -n $SERVER_METRICS ]] || die "$config: no metrics endpoint"
    "$BIN" probe --url "http://$SERVER_METRICS/readyz" || die "$config: /readyz did not answer 200"
    secured=""
    if [[ $tls == 1 && $tokens == 1 ]]; then
        # The secure setup as shipped: TLS with the CA, a token from `humem token`.
        url="https://127.0.0.1:${SERVER_GRPC##*:}"
        token=$("$BIN" token add --file "$TMP/$name-tokens.json" --robot check-deploy 2>/dev/null)
        ok=""
        for _ in $(seq 20); do  # the server reads the token file again within a second
            if "$BIN" stats --server "$url" --tls-ca "$TMP/certs/ca.crt" --token "$token" >/dev/null 2>&1; then ok=1; break; fi
            sleep 0.1
        done
        [[ -n $ok ]] || die "$config: Stats over TLS with a fresh token failed"
        if "$BIN" stats --server "$url" --tls-ca "$TMP/certs/ca.crt" >/dev/null 2>&1; then
            die "$config: Stats without a token was answered"
        fi
        secured="; TLS with a token answered, no token refused"
    fi
    stop_humem || die "$config: humem did not stop cleanly on SIGTERM"
    echo "$config: accepted on $host (models loaded, gRPC and metrics up, /readyz 200$secured, clean SIGTERM)$(grep -q 'running on the CPU' "$TMP/$name.err" && echo '; GPU provider fell back to the CPU in this build')"
done
sed 's/^data_dir =/data_dri =/' deploy/systemd/humem.toml >"$TMP/typo.toml"
SERVER_ENV=(HUMEM_PERCEPTION__ENABLED=false)
if start_humem config-typo --config "$TMP/typo.toml" 2>/dev/null; then
    die "humem serve accepted an unknown key (data_dri): the configuration check proves nothing"
fi
grep -q data_dri "$TMP/config-typo.err" || die "humem refused the typo'd configuration without naming the key"
echo "a typo (data_dri) is refused: $(grep -o 'unknown field.*' "$TMP/config-typo.err" | head -1)"
# The settings the ORB-SLAM3 harness gives its server (client-cpp/orbslam3/harness/server-env.sh,
# used by run.sh) for the data sets' cameras: `humem serve` must accept them, or the harness cannot start.
for size in "512 288" "1241 376" "160 120"; do
    mapfile -t harness_env < <(client-cpp/orbslam3/harness/server-env.sh $size)
    SERVER_ENV=(HUMEM_SERVER__LISTEN=127.0.0.1:0 HUMEM_METRICS__LISTEN=127.0.0.1:0
                HUMEM_STORE__DATA_DIR="$TMP/harness-env-data" HUMEM_PERCEPTION__MODELS_DIR="$REPO/models"
                "${harness_env[@]}")
    start_humem harness-env || die "humem serve refused the harness's settings for a ${size/ /x} camera: ${harness_env[*]} (log above)"
    stop_humem || die "humem did not stop cleanly after the harness's settings"
    echo "the ORB-SLAM3 harness's server settings for a ${size/ /x} camera are accepted: ${harness_env[*]}"
done

# --- 7. live: humem + load generator + Prometheus -----------------------------------------------
step "live: humem serve + humem load + Prometheus, then every dashboard query and alert operand"
mkdir -p "$TMP/images"
unzip -q -j models/testdata/scikit_image-*.whl -d "$TMP/images" \
    skimage/data/astronaut.png skimage/data/chelsea.png skimage/data/coffee.png \
    skimage/data/motorcycle_left.png skimage/data/rocket.jpg skimage/data/text.png
# The defaults (what scripts/run.sh serves) with the real models; ports and store here.
SERVER_ENV=(HUMEM_METRICS__LISTEN=127.0.0.1:0 HUMEM_PERCEPTION__MODELS_DIR="$REPO/models")
start_humem live --listen 127.0.0.1:0 --data-dir "$TMP/live-data" || die "humem serve did not start"
HUMEM_PID=$SERVER_PID
echo "humem: gRPC $SERVER_GRPC, metrics $SERVER_METRICS"

PROM_PORT=$($PY -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
cat >"$TMP/prometheus.yml" <<EOF
# deploy/prometheus/prometheus.yml's job and rules, scraping the server of this check every second.
global:
  scrape_interval: 1s
  evaluation_interval: 1s
rule_files:
  - $REPO/deploy/prometheus/rules/*.rules.yml
scrape_configs:
  - job_name: humem
    static_configs:
      - targets: ["$SERVER_METRICS"]
EOF
prometheus --config.file="$TMP/prometheus.yml" --storage.tsdb.path="$TMP/prometheus" \
    --web.listen-address="127.0.0.1:$PROM_PORT" --log.level=warn >"$TMP/prometheus.log" 2>&1 &
PIDS+=($!)
PROM=http://127.0.0.1:$PROM_PORT
for _ in $(seq 100); do
    $PY -c "import urllib.request as u; u.urlopen('$PROM/-/ready', timeout=1)" 2>/dev/null && break
    sleep 0.2
done
$PY -c "import urllib.request as u; u.urlopen('$PROM/-/ready', timeout=1)" 2>/dev/null \
    || { cat "$TMP/prometheus.log"; die "Prometheus did not become ready"; }
echo "Prometheus $(prometheus --version 2>&1 | head -1 | cut -d' ' -f3) on $PROM"

URL=http://$SERVER_GRPC
load() {  # load NAME ARGS...: humem load in the background, report in $TMP/load-NAME.txt
    local name=$1
    shift
    "$BIN" load --server "$URL" "$@" >"$TMP/load-$name.txt" 2>&1 &
    LOADS+=($!)
    PIDS+=($!)
}
LOADS=()
echo "load: ${LOAD_SECONDS} s of 3 robots x 5 Hz synthetic 1280-d keyframes and loop-closure queries,"
echo "      2 robots x 1 Hz images with image (relocalisation) queries, a 2 s burst of 2 x 25 Hz images,"
echo "      and a client sending 64-d descriptors to a 1280-d store"
load synthetic --robots 3 --rate 5 --duration "$LOAD_SECONDS" --dim 1280 --server-pid "$HUMEM_PID"
load images --robots 2 --rate 1 --duration "$LOAD_SECONDS" --images "$TMP/images" --query-content
# Far more images than any CPU perceives: queries pile up and are superseded.
load burst --robots 2 --rate 25 --duration 2 --images "$TMP/images" --query-content
sleep 5
load wrong-dim --robots 1 --rate 5 --duration 2 --dim 64
for pid in "${LOADS[@]}"; do wait "$pid" || die "humem load failed: $(cat "$TMP"/load-*.txt)"; done
# Then a quiet client whose image queries find the images stored above, so
# that answered queries and returned candidates are in the last minute
# however slowly the contended loads were served (a debug build on 2 cores
# supersedes most of their queries).
"$BIN" load --server "$URL" --robots 1 --rate 0.5 --duration 6 --images "$TMP/images" --query-content \
    >"$TMP/load-answered.txt" 2>&1 || die "humem load failed: $(cat "$TMP"/load-answered.txt)"
for name in synthetic images burst wrong-dim answered; do
    echo "-- humem load ($name)"
    grep -v '^$' "$TMP/load-$name.txt" | sed 's/^/   /'
done
sleep 3  # the last samples scraped and the rules evaluated on them
$PY deploy/checks/check_live.py --prometheus "$PROM" --dashboard deploy/grafana/dashboards/humem.json

SERVER_PID=$HUMEM_PID
stop_humem || die "humem did not stop cleanly on SIGTERM after the load"
echo
echo "check-deploy: all checks passed"
