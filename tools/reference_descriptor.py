#!/usr/bin/env python3
"""The global descriptor of image files, computed the plain Python way.

    reference_descriptor.py MODEL WIDTHxHEIGHT IMAGE... > descriptors.jsonl

The reference the server's own preprocessing is checked against
(tests/e2e/fidelity.rs): Pillow decodes each file and converts it to RGB (a grey
picture has its one channel repeated), squashes it to WIDTHxHEIGHT with Pillow's
antialiased bilinear filter, scales to 0..1 and normalises with the model's
`humem.mean` / `humem.std` metadata, and ONNX Runtime runs the model on the
`[1, 3, H, W]` tensor. The `descriptor` output is L2-normalised again (the
server does the same). Prints one JSON object per image:
{"path": ..., "descriptor": [...]}. Needs numpy, onnxruntime and pillow (the
models venv of scripts/setup-models.sh).
"""
import json
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image

from quantize_models import has_vnni  # tools/ is this script's own folder


def model_is_int8(model):
    """Whether the model is an int8 quantisation (`name.int8.onnx`)."""
    return model.endswith('.int8.onnx')


def describer(model, width, height):
    """A function from an image path to its L2-normalised descriptor."""
    options = ort.SessionOptions()
    if model_is_int8(model) and not has_vnni():
        # As the server does: without VNNI the fast uint8 x int8 kernels
        # saturate; the precise mode gives the VNNI results.
        options.add_session_config_entry('session.x64quantprecision', '1')
    session = ort.InferenceSession(model, options, providers=['CPUExecutionProvider'])
    meta = session.get_modelmeta().custom_metadata_map
    mean = np.array([float(v) for v in meta['humem.mean'].split(',')], np.float32)
    std = np.array([float(v) for v in meta['humem.std'].split(',')], np.float32)

    def describe(path):
        with Image.open(path) as img:
            rgb = img.convert('RGB').resize((width, height), Image.BILINEAR)
        x = (np.asarray(rgb, np.float32) / 255 - mean) / std
        (d,) = session.run(['descriptor'], {'image': x.transpose(2, 0, 1)[None]})
        return d[0] / np.linalg.norm(d[0])

    return describe


def main():
    if len(sys.argv) < 4 or 'x' not in sys.argv[2]:
        sys.exit(__doc__)
    model, size, paths = sys.argv[1], sys.argv[2], sys.argv[3:]
    width, height = (int(v) for v in size.split('x'))
    describe = describer(model, width, height)
    for path in paths:
        d = describe(path)
        print(json.dumps({'path': path, 'descriptor': [round(float(v), 7) for v in d]}))


if __name__ == '__main__':
    main()
