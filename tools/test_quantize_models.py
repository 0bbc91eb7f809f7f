#!/usr/bin/env python3
"""Check the int8 models of tools/quantize_models.py against the fp32 ones and the committed tables.

    python tools/test_quantize_models.py MODELS_DIR

Needs what scripts/setup-models.sh installs in MODELS_DIR: the fp32 and int8 models, the venv
(this script re-runs itself with MODELS_DIR/.venv/bin/python) and the scikit-image wheel in
MODELS_DIR/testdata/. Checks that quantising is byte-for-byte reproducible and gives what setup
installed, that the graphs really are int8 QDQ graphs, that the int8 models stay close to fp32
on pictures and rendered text that calibration did not see (bounds set a little below what was
measured, tools/README.md), and that calibrating again reproduces the committed ranges tables
(tools/quantization/). Sessions are made as measure_quantized.py makes them (on a CPU without
VNNI, with ONNX Runtime's exact session.x64quantprecision). No network. Takes about three
minutes on two cores.
"""
import glob
import hashlib
import io
import os
import sys
import tempfile
import zipfile

MODELS = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else 'models')
VENV_PYTHON = os.path.join(MODELS, '.venv', 'bin', 'python')
if os.path.realpath(sys.prefix) != os.path.realpath(os.path.join(MODELS, '.venv')) and os.path.exists(VENV_PYTHON):
    os.execv(VENV_PYTHON, [VENV_PYTHON, os.path.abspath(__file__), MODELS])

import checks  # noqa: E402  (tools/checks.py)
import measure_quantized as mq  # noqa: E402
import numpy as np  # noqa: E402
import onnx  # noqa: E402
import quantize_models as qm  # noqa: E402
from onnx import TensorProto  # noqa: E402
from PIL import Image  # noqa: E402

TABLES = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'quantization')
RANGE_TOLERANCE = 2e-3  # of a tensor's largest |bound|: one histogram bin of the Percentile calibrator
ESPRESSO, CATS = 967, {281, 282, 283, 285}
(WHEEL,) = glob.glob(os.path.join(MODELS, 'testdata', 'scikit_image-*.whl'))
PICTURES = qm.sample_pictures(WHEEL)


def paths(name):
    """(fp32 model, int8 model, ranges table) of a model."""
    base = os.path.join(MODELS, mq.FILES[name])
    return base + '.onnx', base + '.int8.onnx', os.path.join(TABLES, f'{name}.ranges.json')


def sha256(path):
    with open(path, 'rb') as f:
        return hashlib.sha256(f.read()).hexdigest()


def check_quantize_is_reproducible():
    details, ok = [], True
    with tempfile.TemporaryDirectory() as tmp:
        for name in qm.MODELS:
            fp32, int8, table = paths(name)
            shas = []
            for i in range(2):
                out = os.path.join(tmp, f'{name}.{i}.onnx')
                qm.quantize(fp32, table, out)
                shas.append(sha256(out))
            same = shas[0] == shas[1] == sha256(int8)
            ok &= same
            differ = f' / {shas[1][:12]}, installed {sha256(int8)[:12]}'
            details.append(f'{name} {shas[0][:12]}{"" if same else differ}')
    return ok, 'quantized twice, same bytes as installed: ' + ', '.join(details)


def check_int8_graphs():
    details, ok = [], True
    for name in qm.MODELS:
        fp32, int8, _ = paths(name)
        model = onnx.load(int8)
        ops = {n.op_type for n in model.graph.node}
        int8_weights = [t for t in model.graph.initializer if t.data_type == TensorProto.INT8 and len(t.dims) >= 2]
        fp32_convs = sum(n.op_type in ('Conv', 'ConvTranspose') for n in onnx.load(fp32).graph.node)
        meta = {p.key: p.value for p in model.metadata_props}
        good = ({'QuantizeLinear', 'DequantizeLinear'} <= ops and len(int8_weights) >= fp32_convs
                and meta.get('humem.precision') == 'int8' and sha256(fp32) in meta.get('humem.quantized_from', ''))
        ok &= good
        details.append(f'{name} {len(int8_weights)} int8 weights for {fp32_convs} convolutions')
    return ok, ', '.join(details)


def check_metadata_copied():
    fp32, int8, _ = paths('efficientnet_lite0')
    a, b = qm.model_metadata(fp32), qm.model_metadata(int8)
    missing = [k for k in a if k.startswith('humem.') and a[k] != b.get(k)]
    return not missing, f'humem.* of fp32 in int8: {sorted(k for k in b if k.startswith("humem."))}' + \
        (f', missing or changed {missing}' if missing else '')


def efficientnet():
    fp32, int8 = mq.pair(MODELS, 'efficientnet_lite0', threads=2)
    meta = fp32.get_modelmeta().custom_metadata_map
    mean, std = ([float(v) for v in meta[k].split(',')] for k in ('humem.mean', 'humem.std'))
    return fp32, int8, mean, std


def check_descriptor_close():
    fp32, int8, mean, std = efficientnet()
    whole, held = mq.efficientnet_eval_inputs(PICTURES, mean, std)
    s, h = mq.descriptor_agreement(fp32, int8, whole), mq.descriptor_agreement(fp32, int8, held)
    ok = s['cos_mean'] >= 0.97 and s['cos_min'] >= 0.85 and h['cos_mean'] >= 0.97 and h['cos_min'] >= 0.8
    return ok, (f'cosine int8 vs fp32 at 384x288: samples mean {s["cos_mean"]:.4f} min {s["cos_min"]:.4f}, '
                f'held-out mean {h["cos_mean"]:.4f} min {h["cos_min"]:.4f} '
                f'(want means >= 0.97, mins >= 0.85 / 0.8)')


def check_scene_classes_kept():
    _, int8, mean, std = efficientnet()
    with zipfile.ZipFile(WHEEL) as z:
        tops = [int(mq.run(int8, qm.efficientnet_input(Image.open(io.BytesIO(z.read(f'skimage/data/{n}.png'))),
                                                        mean, std, size=(224, 224)))[1].argmax())
                for n in ('coffee', 'chelsea')]
    return tops[0] == ESPRESSO and tops[1] in CATS, \
        f'int8 top-1: coffee {tops[0]} (want {ESPRESSO}), chelsea {tops[1]} (want a cat)'


def check_detector_close():
    fp32, int8 = mq.pair(MODELS, 'ppocrv5_det', threads=2)
    rng = np.random.default_rng(mq.EVAL_SEED)
    scenes = [qm.detector_input(s) for _, s in qm.detector_scenes(PICTURES, rng, 20)]
    diffs, matched, total = [], 0, 0
    for x in scenes:
        p0, p1 = mq.run(fp32, x)[0][0, 0], mq.run(int8, x)[0][0, 0]
        diffs.append(float(np.abs(p0 - p1).mean()))
        b0, b1 = mq.text_boxes(p0), mq.text_boxes(p1)
        total += len(b0)
        matched += sum(any(mq.iou(a, b) >= 0.5 for b in b1) for a in b0)
    mad = float(np.mean(diffs))
    return mad <= 0.02 and matched >= 0.9 * total and total >= 40, \
        f'20 text scenes: probability mean |diff| {mad:.4f} (want <= 0.02), ' \
        f'{matched}/{total} fp32 boxes found by int8 (want >= 90 %)'


def check_recognizer_reads_alike():
    fp32, int8 = mq.pair(MODELS, 'ppocrv5_rec', threads=2)
    read = mq.readings(fp32, int8, mq.rendered_lines(PICTURES, 100), mq.dictionary(MODELS))
    agree, right32, right8 = mq.reading_agreement(read)
    return agree >= 0.75 and right8 >= right32 - 0.05, \
        f'100 rendered lines: int8 reads as fp32 {agree:.0%} (want >= 75 %), ' \
        f'right: fp32 {right32:.0%}, int8 {right8:.0%} (want int8 >= fp32 - 5 %)'


def check_calibration_reproduces_tables():
    details, ok = [], True
    with tempfile.TemporaryDirectory() as tmp:
        qm.calibrate(MODELS, WHEEL, tmp)
        for name in qm.MODELS:
            committed = qm.read_table(paths(name)[2])
            again = qm.read_table(os.path.join(tmp, f'{name}.ranges.json'))
            worst = max(range_drift(committed['ranges'][k], again['ranges'].get(k)) for k in committed['ranges'])
            same_inputs = committed['calibration']['inputs_sha256'] == again['calibration']['inputs_sha256']
            same_keys = committed['ranges'].keys() == again['ranges'].keys()
            ok &= same_inputs and same_keys and worst <= RANGE_TOLERANCE
            details.append(f'{name} inputs {"same" if same_inputs else "DIFFER"}, '
                           f'{"same" if same_keys else "OTHER"} tensors, worst drift {worst:.1e}')
    return ok, ', '.join(details) + f' (want <= {RANGE_TOLERANCE})'


def range_drift(a, b):
    """How far range b is from a, relative to a's largest |bound|; inf if b is missing."""
    if b is None:
        return float('inf')
    scale = max(abs(a[0]), abs(a[1]), 1e-6)
    return max(abs(a[0] - b[0]), abs(a[1] - b[1])) / scale


checks.run((check_quantize_is_reproducible, check_int8_graphs, check_metadata_copied, check_descriptor_close,
            check_scene_classes_kept, check_detector_close, check_recognizer_reads_alike,
            check_calibration_reproduces_tables))
