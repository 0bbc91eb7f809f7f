#!/usr/bin/env python3
"""Check the tiny constant-output YOLO models of tools/make_tiny_yolo.py.

    python tools/test_make_tiny_yolo.py

Generates the models in a temporary directory (re-running itself with the repo's
models/.venv/bin/python if that exists), runs them with onnxruntime at batch 1 and 3
(random and NaN inputs) and checks that the outputs equal the intended constants
bit for bit, then decodes them with a small independent numpy decoder (conf 0.25,
class-aware NMS at IoU 0.45, masks at prototype resolution) to check EXPECTED.md's
numbers. Exits non-zero on any failure.
"""
import atexit
import os
import shutil
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, '..', 'models', '.venv')
VENV_PYTHON = os.path.join(VENV, 'bin', 'python')
if os.path.realpath(sys.prefix) != os.path.realpath(VENV) and os.path.exists(VENV_PYTHON):
    os.execv(VENV_PYTHON, [VENV_PYTHON, os.path.abspath(__file__)])

import checks  # noqa: E402  (tools/checks.py)
import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402

sys.dont_write_bytecode = True  # no tools/__pycache__
sys.path.insert(0, HERE)
import make_tiny_yolo as tiny  # noqa: E402

OUT = tempfile.mkdtemp(prefix='tiny_yolo_')
atexit.register(shutil.rmtree, OUT, True)
sys.argv = ['make_tiny_yolo.py', OUT]
tiny.main()
seg = ort.InferenceSession(os.path.join(OUT, 'yolo_seg_anchors.onnx'), providers=['CPUExecutionProvider'])
e2e = ort.InferenceSession(os.path.join(OUT, 'yolo_end_to_end.onnx'), providers=['CPUExecutionProvider'])
SEG0, SEG1 = tiny.seg_tensors()
E2E0 = tiny.end_to_end_tensor()
rng = np.random.default_rng(0)


def images(n, fill=None):
    x = rng.standard_normal((n, 3, 64, 64)).astype(np.float32)
    return x if fill is None else np.full_like(x, fill)


def same(got, want, n):
    """got is exactly want [1, ...] repeated n times (bitwise, NaN-free)."""
    return got.shape == (n, *want.shape[1:]) and got.dtype == np.float32 and \
        np.array_equal(got, np.broadcast_to(want, got.shape))


def check_io_names():
    names = ([(i.name, i.shape) for i in seg.get_inputs()], [(o.name, o.shape) for o in seg.get_outputs()],
             [(o.name, o.shape) for o in e2e.get_outputs()])
    want = ([('images', ['N', 3, 64, 64])], [('output0', ['N', 39, 8]), ('output1', ['N', 32, 16, 16])],
            [('output0', ['N', 5, 6])])
    return names == want, f'{names}'


def check_seg_constants():
    ok, shapes = True, []
    for n, fill in ((1, None), (3, None), (3, np.nan), (1, np.inf)):
        out0, out1 = seg.run(['output0', 'output1'], {'images': images(n, fill)})
        ok &= same(out0, SEG0, n) and same(out1, SEG1, n)
        shapes.append(f'N={n} fill={fill}: {out0.shape} {out1.shape}')
    return ok, '; '.join(shapes)


def check_e2e_constants():
    ok, shapes = True, []
    for n, fill in ((1, None), (3, None), (3, np.nan)):
        (out0,) = e2e.run(['output0'], {'images': images(n, fill)})
        ok &= same(out0, E2E0, n)
        shapes.append(f'N={n} fill={fill}: {out0.shape}')
    return ok, '; '.join(shapes)


def check_spot_values():
    # A few hand-written values, so the constants are not only checked against themselves.
    a0, a2 = SEG0[0, :, 0], SEG0[0, :, 2]
    ok = list(a0[:7]) == [16, 16, 16, 16, np.float32(0.9), 0, 0] and a0[7] == 1 and a0[8:].sum() == 0 \
        and list(a2[:7]) == [48, 40, 16, 32, 0, np.float32(0.8), 0] and a2[8] == 1 and a2[7:].sum() == 1 \
        and (SEG0[0, 4:7, 4:] == 0).all() and (SEG1[0, 0] > 0).sum() == 8 and (SEG1[0, 1] > 0).sum() == 32 \
        and (SEG1[0, 2:] == -10).all() and SEG1[0, 0, 2, 2] == 10 and SEG1[0, 0, 4, 2] == -10
    return bool(ok), 'anchor 0 / 2 columns, empty anchors 4..7, prototype pixel counts 8 / 32'


def iou(a, b):
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(w, 0) * max(h, 0)
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def nms(dets, thr=0.45):
    kept = []
    for d in sorted(dets, key=lambda d: -d[1]):
        if not any(k[0] == d[0] and iou(k[2], d[2]) > thr for k in kept):
            kept.append(d)
    return kept


def mask_stats(coeffs, protos, box, cell=4):
    """Area and centroid (input px) of coeffs·protos > 0, proto pixels with centres in box."""
    logits = np.tensordot(coeffs, protos, 1)
    ys, xs = np.mgrid[0:logits.shape[0], 0:logits.shape[1]]
    cx, cy = (xs + 0.5) * cell, (ys + 0.5) * cell
    on = (logits > 0) & (cx >= box[0]) & (cx < box[2]) & (cy >= box[1]) & (cy < box[3])
    return float(on.sum() * cell * cell), (float(cx[on].mean()), float(cy[on].mean()))


def check_seg_decode():
    out0, out1 = seg.run(['output0', 'output1'], {'images': images(1)})
    p = out0[0]
    dets = []
    for a in range(p.shape[1]):
        scores = p[4:4 + tiny.NC, a]
        cls, score = int(scores.argmax()), float(scores.max())
        if score > 0.25:
            cx, cy, w, h = p[:4, a]
            dets.append((cls, score, (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2), p[4 + tiny.NC:, a]))
    got = [(c, round(s, 6), tuple(float(v) for v in b), mask_stats(m, out1[0], b)) for c, s, b, m in nms(dets)]
    want = [(0, 0.9, (8, 8, 24, 24), (128, (16, 12))), (1, 0.8, (40, 24, 56, 56), (512, (48, 40)))]
    return got == want and len(dets) == 3, f'{len(dets)} above 0.25, after NMS {got}'


def check_e2e_decode():
    (out0,) = e2e.run(['output0'], {'images': images(1)})
    got = [(int(r[5]), round(float(r[4]), 6), tuple(float(v) for v in r[:4])) for r in out0[0] if r[4] > 0.25]
    want = [(0, 0.9, (8, 8, 24, 24)), (1, 0.8, (40, 24, 56, 56))]
    return got == want, f'{got}'


def check_expected_md():
    text = open(os.path.join(OUT, 'EXPECTED.md')).read()
    return all(s in text for s in ('(16, 12)', '(48, 40)', '128', '512')), 'EXPECTED.md mentions areas and centroids'


checks.run((check_io_names, check_seg_constants, check_e2e_constants, check_spot_values,
              check_seg_decode, check_e2e_decode, check_expected_md))
