#!/usr/bin/env python3
"""Check the converted EfficientNet-Lite0 ONNX model on real pictures.

    python tools/test_efficientnet_to_onnx.py MODELS_DIR

Needs what scripts/setup-models.sh installs in MODELS_DIR: the model, the venv (this
script re-runs itself with MODELS_DIR/.venv/bin/python) and the scikit-image wheel in
MODELS_DIR/testdata/, whose sample pictures are read straight from the zip. No network.
"""
import glob
import io
import os
import sys
import zipfile

MODELS = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else 'models')
VENV_PYTHON = os.path.join(MODELS, '.venv', 'bin', 'python')
if os.path.realpath(sys.prefix) != os.path.realpath(os.path.join(MODELS, '.venv')) and os.path.exists(VENV_PYTHON):
    os.execv(VENV_PYTHON, [VENV_PYTHON, os.path.abspath(__file__), MODELS])

import checks  # noqa: E402  (tools/checks.py)
import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
from PIL import Image  # noqa: E402

ESPRESSO, CATS = 967, {281: 'tabby', 282: 'tiger cat', 283: 'Persian', 285: 'Egyptian cat'}

session = ort.InferenceSession(os.path.join(MODELS, 'efficientnet-lite0', 'efficientnet_lite0.onnx'),
                               providers=['CPUExecutionProvider'])
meta = session.get_modelmeta().custom_metadata_map
MEAN = np.array([float(v) for v in meta['humem.mean'].split(',')], np.float32)
STD = np.array([float(v) for v in meta['humem.std'].split(',')], np.float32)
(wheel,) = glob.glob(os.path.join(MODELS, 'testdata', 'scikit_image-*.whl'))
samples = zipfile.ZipFile(wheel)


def picture(name, size=(224, 224)):
    """A sample picture as a normalised [1, 3, H, W] tensor; size is (width, height)."""
    img = Image.open(io.BytesIO(samples.read(f'skimage/data/{name}.png'))).convert('RGB')
    rgb = np.asarray(img.resize(size, Image.BILINEAR), np.float32) / 255
    return ((rgb - MEAN) / STD).transpose(2, 0, 1)[None].astype(np.float32)


def run(x):
    return dict(zip(['descriptor', 'scene'], session.run(['descriptor', 'scene'], {'image': x})))


coffee, chelsea = picture('coffee'), picture('chelsea')
out_coffee, out_chelsea = run(coffee), run(chelsea)


def check_coffee():
    top = int(out_coffee['scene'][0].argmax())
    return top == ESPRESSO, f'top-1 {top} p={out_coffee["scene"][0, top]:.3f} (want {ESPRESSO} espresso)'


def check_chelsea():
    top = int(out_chelsea['scene'][0].argmax())
    return top in CATS, f'top-1 {top} {CATS.get(top, "")} p={out_chelsea["scene"][0, top]:.3f} (want a cat)'


def check_descriptor():
    d = out_coffee['descriptor']
    norm = float(np.linalg.norm(d))
    return d.shape == (1, 1280) and abs(norm - 1) < 1e-4, f'shape {d.shape}, L2 norm {norm:.6f}'


def check_batch():
    both = run(np.concatenate([coffee, chelsea]))
    diff = max(float(np.abs(both[k] - np.concatenate([out_coffee[k], out_chelsea[k]])).max())
               for k in ('descriptor', 'scene'))
    return diff < 1e-4, f'batch of 2 vs two singles: max |diff| {diff:.2e}'


def check_non_square():
    out = run(picture('coffee', size=(512, 384)))  # H=384, W=512
    d, s = out['descriptor'], out['scene']
    ok = d.shape == (1, 1280) and s.shape == (1, 1000) and abs(np.linalg.norm(d) - 1) < 1e-4 \
        and abs(s.sum() - 1) < 1e-4 and int(s.argmax()) == ESPRESSO
    return ok, f'384x512: descriptor {d.shape}, scene {s.shape}, top-1 {int(s.argmax())}'


def check_metadata():
    ok = len(MEAN) == len(STD) == 3 and 'sha256=' in meta.get('humem.source', '')
    return ok, f'mean {meta["humem.mean"]}, std {meta["humem.std"]}, source {meta.get("humem.source")}'


checks.run((check_coffee, check_chelsea, check_descriptor, check_batch, check_non_square, check_metadata))
