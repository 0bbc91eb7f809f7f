#!/usr/bin/env bash
# The HuMem ORB-SLAM3 harness: builds patched ORB-SLAM3 v1.0 with the HuMem
# plugin from a checkout you supply, trains (or reuses) a vocabulary, runs a
# monocular data-set folder with the plugin (a fresh `humem serve` per run)
# and with plain DBoW2, and prints one table (see ../README.md, "Harness").
#
#   client-cpp/orbslam3/harness/run.sh --orbslam3 ~/src/ORB_SLAM3 --pangolin ~/pangolin-v0.6 \
#       --dataset /path/to/town-dev/loop --humem target/release/humem [--runs 3]
#
# Nothing is written into the checkout: it is copied to WORK/orbslam3, the
# patch is applied to the copy, and the builds live under WORK (reused by the
# next invocation; only files whose content changed are rebuilt).
set -euo pipefail

# Everything is in main, which bash parses whole before running it: editing
# this file while it runs cannot change what the running copy does.
main() {
here=$(cd "$(dirname "$0")" && pwd)
plugin_dir=$(cd "$here/.." && pwd)           # client-cpp/orbslam3
client_dir=$(cd "$plugin_dir/.." && pwd)     # client-cpp
repo=$(cd "$client_dir/.." && pwd)

usage() {
    cat <<EOF
usage: $0 --orbslam3 DIR --pangolin PREFIX --dataset DIR [options]
  --orbslam3 DIR      ORB-SLAM3 v1.0 checkout (commit 0df83dd); it is copied, never changed
  --pangolin PREFIX   Pangolin v0.6 install prefix
  --dataset DIR       data-set folder with sequence/ (images), sequence_calib.json and
                      sequence_poses.txt (TUM, camera-to-world), e.g. town-dev/loop
  --humem BIN         humem binary (default: $repo/target/release/humem)
  --runs N            runs per mode (default 3)
  --modes "M..."      humem, dbow2 and modes named by --mode-env (default "humem dbow2");
                      runs alternate between modes
  --mode-env NAME "K=V ..."   a further HuMem mode NAME (humem-...) whose server gets these
                      variables on top of --server-env (repeatable), e.g.
                      --mode-env humem-no-envelope "HUMEM_VPR__MAX_DRIFT_RATIO=1"
  --work DIR          build and run cache (default: \$HOME/.cache/humem-orbslam3)
  --fps F             frames fed per second, wall clock (default 10, the data's rate for
                      town-dev; lower it on a loaded machine: Local Mapping must keep up)
  --vocab FILE        use this vocabulary (text, as ORBvoc.txt) instead of training one
  --vocab-images "D..."  image folders to train on (default: every image folder of the
                      data set's sibling folders, never the evaluated one)
  --vocab-max-images N   at most N training images, evenly spaced (default 400)
  --vocab-k K --vocab-l L  branching factor and depth (default 10 and 5)
  --server-env "K=V ..."   environment for humem serve (default: server-env.sh WIDTH HEIGHT
                      of the camera: the OCR detector's long side = the camera's long side,
                      rounded down to a multiple of 32)
  --humem-setting "HuMem.Key: value"   a further plugin setting for the HuMem runs (repeatable),
                      e.g. "HuMem.VerifyBelowScore: 0.5"
  --realtime          feed strictly by the clock; by default a frame also waits until Local
                      Mapping has taken the queued keyframes (a loaded machine cannot keep up)
  --build-only        build (and train the vocabulary), run nothing
  --evaluate-only DIR evaluate an earlier run folder again
Environment: PYTHON (python3 with numpy; default python3), JOBS (2), NICE (10),
HUMEM_PERCEPTION__MODELS_DIR (default: $repo/models).
EOF
}

orbslam3="" pangolin="" dataset="" humem="$repo/target/release/humem" runs=3 modes="humem dbow2"
work="${HOME}/.cache/humem-orbslam3" fps=10 vocab="" vocab_images="" vocab_max=400 vocab_k=10 vocab_l=5
server_env="" build_only=0 evaluate_only="" realtime=0 humem_settings=()
declare -A mode_env=()
while [ $# -gt 0 ]; do
    case "$1" in
        --orbslam3) orbslam3=$2; shift 2 ;;
        --pangolin) pangolin=$2; shift 2 ;;
        --dataset) dataset=$2; shift 2 ;;
        --humem) humem=$2; shift 2 ;;
        --runs) runs=$2; shift 2 ;;
        --modes) modes=$2; shift 2 ;;
        --work) work=$2; shift 2 ;;
        --fps) fps=$2; shift 2 ;;
        --vocab) vocab=$2; shift 2 ;;
        --vocab-images) vocab_images=$2; shift 2 ;;
        --vocab-max-images) vocab_max=$2; shift 2 ;;
        --vocab-k) vocab_k=$2; shift 2 ;;
        --vocab-l) vocab_l=$2; shift 2 ;;
        --server-env) server_env=$2; shift 2 ;;
        --mode-env)
            case "$2" in humem-*) ;; *) echo "run.sh: --mode-env names a mode humem-..., got: $2" >&2; exit 2 ;; esac
            mode_env[$2]=$3; shift 3 ;;
        --build-only) build_only=1; shift ;;
        --realtime) realtime=1; shift ;;
        --humem-setting)
            case "$2" in HuMem.*:*) ;; *) echo "run.sh: --humem-setting wants \"HuMem.Key: value\", got: $2" >&2; exit 2 ;; esac
            humem_settings+=("$2"); shift 2 ;;
        --evaluate-only) evaluate_only=$2; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "run.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
    esac
done
PYTHON=${PYTHON:-python3}
JOBS=${JOBS:-2}
NICE=${NICE:-10}
export HUMEM_PERCEPTION__MODELS_DIR=${HUMEM_PERCEPTION__MODELS_DIR:-$repo/models}
abspath() { (cd "$1" && pwd); }
log() { echo "== harness: $*" >&2; }
die() { echo "run.sh: $*" >&2; exit 1; }

if [ -n "$evaluate_only" ]; then
    [ -n "$dataset" ] || die "--evaluate-only needs --dataset"
    exec "$PYTHON" "$here/evaluate.py" --dataset "$dataset" --runs-dir "$evaluate_only"
fi

[ -n "$orbslam3" ] && [ -d "$orbslam3/src" ] && [ -f "$orbslam3/include/KeyFrameDatabase.h" ] \
    || die "--orbslam3 must name an ORB-SLAM3 v1.0 checkout (got '$orbslam3')"
[ -n "$pangolin" ] && [ -d "$pangolin" ] || die "--pangolin must name a Pangolin v0.6 install prefix"
orbslam3=$(abspath "$orbslam3"); pangolin=$(abspath "$pangolin")
if [ "$build_only" = 0 ]; then
    [ -n "$dataset" ] && [ -d "$dataset/sequence" ] || die "--dataset must name a folder with sequence/"
    dataset=$(abspath "$dataset")
    for mode in $modes; do
        case "$mode" in
            humem|dbow2) ;;
            humem-*) [ -n "${mode_env[$mode]+set}" ] || die "mode $mode has no --mode-env $mode \"K=V ...\"" ;;
            *) die "unknown mode $mode (humem, dbow2, or humem-... with --mode-env)" ;;
        esac
    done
    case " $modes " in *" humem"*) [ -x "$humem" ] || die "humem binary not found: $humem (--humem)" ;; esac
fi
if [ -n "$dataset" ]; then dataset=$(abspath "$dataset"); fi
mkdir -p "$work"; work=$(abspath "$work")
run_nice() { nice -n "$NICE" "$@"; }

# ---------------------------------------------------------------------------
# 1. The HuMem C++ client, installed to WORK/humem-client.
log "HuMem C++ client -> $work/humem-client"
run_nice cmake -S "$client_dir" -B "$work/humem-client-build" -DCMAKE_BUILD_TYPE=Release \
    -DHUMEM_CLIENT_BUILD_TESTS=OFF >"$work/humem-client-build.log" 2>&1 \
    || { cat "$work/humem-client-build.log" >&2; die "configuring the HuMem client failed"; }
run_nice cmake --build "$work/humem-client-build" -j"$JOBS" >>"$work/humem-client-build.log" 2>&1 \
    || { tail -50 "$work/humem-client-build.log" >&2; die "building the HuMem client failed"; }
cmake --install "$work/humem-client-build" --prefix "$work/humem-client" >>"$work/humem-client-build.log" 2>&1

# ---------------------------------------------------------------------------
# 2. Copy the checkout, apply the patch to the copy. The copy is staged, and
#    only files whose content differs are copied over the cached tree, so
#    make rebuilds only what changed.
src="$work/orbslam3"
stage="$work/orbslam3.stage"
log "ORB-SLAM3 $orbslam3 -> $src (+ orbslam3-v1.0.patch)"
rm -rf "$stage"; mkdir -p "$stage"
(cd "$orbslam3" && tar --exclude=./.git --exclude=./build --exclude=./lib \
    --exclude=./Thirdparty/DBoW2/build --exclude=./Thirdparty/DBoW2/lib \
    --exclude=./Thirdparty/g2o/build --exclude=./Thirdparty/g2o/lib --exclude=./Thirdparty/g2o/config.h \
    -cf - .) | (cd "$stage" && tar -xf -)
(cd "$stage" && patch -p1 --quiet --forward < "$plugin_dir/orbslam3-v1.0.patch") \
    || die "orbslam3-v1.0.patch does not apply to $orbslam3 (it needs ORB-SLAM3 v1.0, commit 0df83dd)"
mkdir -p "$src"
(cd "$stage" && find . -type f) | while IFS= read -r f; do
    if ! cmp -s "$stage/$f" "$src/$f"; then
        mkdir -p "$(dirname "$src/$f")"; cp -p "$stage/$f" "$src/$f"
    fi
done
rm -rf "$stage"

# ---------------------------------------------------------------------------
# 3. Thirdparty (as ORB-SLAM3's build.sh, with -std=c++11 like the library).
for tp in DBoW2 g2o; do
    log "Thirdparty/$tp"
    run_nice cmake -S "$src/Thirdparty/$tp" -B "$src/Thirdparty/$tp/build" -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_CXX_FLAGS=-std=c++11 >"$work/$tp-build.log" 2>&1 \
        && run_nice make -C "$src/Thirdparty/$tp/build" -j"$JOBS" >>"$work/$tp-build.log" 2>&1 \
        || { tail -50 "$work/$tp-build.log" >&2; die "building Thirdparty/$tp failed"; }
done

# 4. libORB_SLAM3 with the plugin (the library target only).
log "libORB_SLAM3 with the HuMem plugin (the first build takes 15-25 min on 2 cores; log: $work/orbslam3-build.log)"
run_nice cmake -S "$src" -B "$src/build" -DCMAKE_BUILD_TYPE=Release \
    -DORB_SLAM3_PLUGIN="$plugin_dir/orbslam3-humem.cmake" \
    -DCMAKE_PREFIX_PATH="$work/humem-client;$pangolin" >"$work/orbslam3-build.log" 2>&1 \
    && run_nice make -C "$src/build" -j"$JOBS" ORB_SLAM3 >>"$work/orbslam3-build.log" 2>&1 \
    || { tail -60 "$work/orbslam3-build.log" >&2; die "building libORB_SLAM3 failed"; }

# 5. The driver and the vocabulary trainer.
log "driver and vocabulary trainer -> $work/harness-build"
run_nice cmake -S "$here" -B "$work/harness-build" -DCMAKE_BUILD_TYPE=Release -DORB_SLAM3_DIR="$src" \
    -DCMAKE_PREFIX_PATH="$work/humem-client;$pangolin" >"$work/harness-build.log" 2>&1 \
    && run_nice cmake --build "$work/harness-build" -j"$JOBS" >>"$work/harness-build.log" 2>&1 \
    || { tail -60 "$work/harness-build.log" >&2; die "building the driver failed"; }
driver="$work/harness-build/humem_orbslam3_mono"
trainer="$work/harness-build/humem_orbslam3_vocab"
export LD_LIBRARY_PATH="$src/lib:$src/Thirdparty/DBoW2/lib:$src/Thirdparty/g2o/lib:$work/humem-client/lib:$pangolin/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"

# ---------------------------------------------------------------------------
# 6. The vocabulary: given, or trained with ORB-SLAM3's DBoW2 on images that
#    are not the evaluated data set's (cached by training set and k, L).
if [ -z "$vocab" ] && [ "$build_only" = 1 ] && [ -z "$vocab_images" ] && [ -z "$dataset" ]; then
    log "built: $driver, $trainer (no vocabulary trained: no --dataset or --vocab-images)"
    exit 0
fi
if [ -z "$vocab" ]; then
    if [ -z "$vocab_images" ]; then
        parent=$(dirname "$dataset")
        vocab_images=$(find "$parent" -mindepth 2 -maxdepth 2 -type d ! -name '*_objects' | sort | while read -r d; do
            case "$d" in "$dataset"|"$dataset"/*) continue ;; esac
            ls "$d" | grep -qiE '\.(jpg|jpeg|png)$' && echo "$d"
        done | tr '\n' ' ')
        [ -n "$vocab_images" ] || die "no image folders beside $dataset to train a vocabulary on: pass --vocab or --vocab-images"
    fi
    for d in $vocab_images; do
        case "$(abspath "$d")" in "$dataset"|"$dataset"/*) die "--vocab-images must not include the evaluated data set ($d)" ;; esac
    done
    key=$(echo "k$vocab_k l$vocab_l max$vocab_max $vocab_images" | sha1sum | cut -c1-12)
    vocab="$work/vocab/voc-k${vocab_k}-l${vocab_l}-$key.txt"
    if [ ! -s "$vocab" ]; then
        log "training a vocabulary (k $vocab_k, L $vocab_l, at most $vocab_max images) on: $vocab_images"
        mkdir -p "$work/vocab"
        # shellcheck disable=SC2086
        run_nice "$trainer" --out "$vocab.tmp" --k "$vocab_k" --l "$vocab_l" --max-images "$vocab_max" \
            $vocab_images >"$vocab.log" 2>&1 || { tail -20 "$vocab.log" >&2; die "vocabulary training failed"; }
        mv "$vocab.tmp" "$vocab"
        echo "$vocab_images" >"$vocab.images"
    else
        log "vocabulary: $vocab (cached; trained on $(cat "$vocab.images" 2>/dev/null))"
    fi
fi
[ -s "$vocab" ] || die "vocabulary $vocab is missing or empty"
[ "$build_only" = 1 ] && { log "built: $driver, $trainer; vocabulary $vocab"; exit 0; }

# ---------------------------------------------------------------------------
# 7. Settings: the camera from the data set's calibration, the HuMem keys.
calib="$dataset/sequence_calib.json"
[ -f "$calib" ] || die "no $calib"
stamp=$(date -u +%Y%m%dT%H%M%SZ)
out="$work/runs/$(basename "$(dirname "$dataset")")-$(basename "$dataset")-$stamp"
mkdir -p "$out"
read -r cw ch < <("$PYTHON" -c 'import json,sys; c=json.load(open(sys.argv[1])); print(c["width"], c["height"])' "$calib")
"$PYTHON" - "$calib" "$fps" "$dataset/sequence_poses.txt" >"$out/camera.yaml" <<'EOF'
import json, os, sys
c = json.load(open(sys.argv[1]))
# Camera.fps is the data's frame rate (ORB-SLAM3 counts frames with it), not
# the feed rate: from the poses' timestamps if there are any.
rate = float(sys.argv[2])
if os.path.exists(sys.argv[3]):
    t = [float(l.split()[0]) for l in open(sys.argv[3]) if l.strip() and not l.startswith("#")]
    d = sorted(b - a for a, b in zip(t, t[1:]) if b > a)
    if d:
        rate = 1.0 / d[len(d) // 2]
d = c.get("distortion", {}) if isinstance(c.get("distortion"), dict) else {}
print('%YAML:1.0')
print('# written by client-cpp/orbslam3/harness/run.sh from ' + sys.argv[1])
print('File.version: "1.0"')
print('Camera.type: "PinHole"')
for k in ("fx", "fy", "cx", "cy"):
    print('Camera1.%s: %.6f' % (k, float(c[k])))
for k in ("k1", "k2", "p1", "p2"):
    print('Camera1.%s: %.6f' % (k, float(d.get(k, 0.0))))
print('Camera.width: %d' % int(c["width"]))
print('Camera.height: %d' % int(c["height"]))
print('Camera.fps: %d' % int(round(rate)))
print('Camera.RGB: 1')
print('ORBextractor.nFeatures: 1000')
print('ORBextractor.scaleFactor: 1.2')
print('ORBextractor.nLevels: 8')
print('ORBextractor.iniThFAST: 20')
print('ORBextractor.minThFAST: 7')
for k, v in (("KeyFrameSize", 0.05), ("KeyFrameLineWidth", 1.0), ("GraphLineWidth", 0.9), ("PointSize", 2.0),
             ("CameraSize", 0.08), ("CameraLineWidth", 3.0), ("ViewpointX", 0.0), ("ViewpointY", -0.7),
             ("ViewpointZ", -1.8), ("ViewpointF", 500.0)):
    print('Viewer.%s: %.2f' % (k, v))
EOF
if [ -z "$server_env" ]; then
    # The server's environment for this camera (server-env.sh: also what a CI check feeds `humem serve`).
    server_env=$("$here/server-env.sh" "$cw" "$ch" | tr '\n' ' ')
fi
timestamps=()
[ -f "$dataset/sequence_poses.txt" ] && timestamps=(--timestamps "$dataset/sequence_poses.txt")
{
    echo "dataset $dataset"; echo "orbslam3 $orbslam3"; echo "vocabulary $vocab"; echo "fps $fps"; echo "realtime $realtime"
    echo "humem $humem"; echo "server_env $server_env"
    for m in "${!mode_env[@]}"; do echo "mode_env $m ${mode_env[$m]}"; done
    echo "patch_sha1 $(sha1sum < "$plugin_dir/orbslam3-v1.0.patch" | cut -c1-12)"
    echo "plugin_sha1 $(cat "$plugin_dir/VprKeyFrameDatabase.cc" "$plugin_dir/VprKeyFrameDatabase.h" | sha1sum | cut -c1-12)"
    echo "host $(hostname) $(nproc) cores"
} >"$out/harness.txt"
[ -x "$humem" ] && "$humem" --version >>"$out/harness.txt" 2>/dev/null || true

free_port() { "$PYTHON" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
server_pid=""
stop_server() {
    if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
        kill -INT "$server_pid" 2>/dev/null || true
        for _ in $(seq 1 100); do kill -0 "$server_pid" 2>/dev/null || break; sleep 0.1; done
        kill -0 "$server_pid" 2>/dev/null && kill -KILL "$server_pid" 2>/dev/null || true
        wait "$server_pid" 2>/dev/null || true
    fi
    server_pid=""
}
trap stop_server EXIT

# 8. The runs, alternating between modes so both see the same machine load.
for i in $(seq 1 "$runs"); do
    for mode in $modes; do
        rd="$out/$mode-$i"
        mkdir -p "$rd"
        cp "$out/camera.yaml" "$rd/settings.yaml"
        echo "mode $mode" >"$rd/run.txt"; echo "run $i" >>"$rd/run.txt"
        if [ "$mode" != dbow2 ]; then
            port=$(free_port)
            metrics=$(free_port)
            # shellcheck disable=SC2086
            (cd "$repo" && exec env $server_env ${mode_env[$mode]:-} HUMEM_METRICS__LISTEN="127.0.0.1:$metrics" \
                "$humem" serve --listen "127.0.0.1:$port" --data-dir "$rd/store") >"$rd/server.log" 2>&1 &
            server_pid=$!
            for _ in $(seq 1 600); do
                (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null && break
                kill -0 "$server_pid" 2>/dev/null || { tail -20 "$rd/server.log" >&2; die "humem serve exited"; }
                sleep 0.1
            done
            printf 'HuMem.Enabled: 1\nHuMem.Address: "127.0.0.1:%s"\nHuMem.RobotId: "orbslam3"\nHuMem.DBoW2Fallback: 0\nHuMem.Verbose: 1\nHuMem.SentLog: "%s"\n' \
                "$port" "$rd/sent.txt" >>"$rd/settings.yaml"
            for setting in "${humem_settings[@]}"; do
                printf '%s\n' "$setting" >>"$rd/settings.yaml"
            done
        else
            printf 'HuMem.Enabled: 0\n' >>"$rd/settings.yaml"
        fi
        log "run $i, $mode -> $rd"
        set +e
        "$driver" --vocabulary "$vocab" --settings "$rd/settings.yaml" --images "$dataset/sequence" \
            --out "$rd" --fps "$fps" --realtime "$realtime" "${timestamps[@]}" >"$rd/orbslam3.log" 2>&1
        rc=$?
        set -e
        echo "driver_rc $rc" >>"$rd/run.txt"
        grep -F '[ORB-SLAM3 event]' "$rd/orbslam3.log" | sed 's/^.*\[ORB-SLAM3 event\] //' >"$rd/events.txt" || true
        [ "$rc" = 0 ] || { log "driver exited with $rc (see $rd/orbslam3.log)"; tail -5 "$rd/orbslam3.log" >&2; }
        if [ "$mode" != dbow2 ]; then
            stop_server
            if "$humem" export --help >/dev/null 2>&1; then
                (cd "$repo" && "$humem" export --data-dir "$rd/store") >"$rd/store.jsonl" 2>"$rd/export.log" \
                    || { log "humem export failed (see $rd/export.log)"; rm -f "$rd/store.jsonl"; }
            else
                log "this humem has no 'export' command: the store check is skipped"
            fi
        fi
    done
done

# 9. One table.
"$PYTHON" "$here/evaluate.py" --dataset "$dataset" --runs-dir "$out" | tee "$out/table.md"
log "runs and table: $out"
}

main "$@"
