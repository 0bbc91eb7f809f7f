#!/usr/bin/env python3
"""Which parts of the PP-OCRv5 text detector survive int8: a sweep over the nodes left in float.

    detector_quant_sweep.py MODELS_DIR TOWN_DEV_DIR [--variants all,head,...] [--ranges TABLE]

Each variant is the detector quantised as tools/quantize_models.py does it (static QDQ from the
committed ranges table), with a different set of nodes kept float. It is run beside the fp32
detector on town-dev frames (every third frame of `loop`, every sixth query of the four other
conditions) at HuMem's detector input (long side 512), and compared where it matters for reading
signs: of the pixels fp32 marks as text (probability > 0.3, DBNet's binarisation threshold), the
share int8 also marks ("kept"), and of those int8 marks, the share fp32 marks too ("agree").
The frames are evaluation frames: this measures, it chooses nothing that ships.
Needs the models and venv of scripts/setup-models.sh.
"""
import argparse
import glob
import os
import sys
import tempfile

import onnx
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import measure_quantized as mq  # noqa: E402
import quantize_models as qm  # noqa: E402

TEXT = 0.3  # DBNet's binarisation threshold (crates/perception/src/ocr/db.rs)


def variants(names):
    """{name: (nodes kept float, op types quantised or None for the shipped list)}."""
    head = names[names.index('Conv.61'):]  # after the neck's concat: the DB head
    found = {
        'all': ([], None),
        'all-but-head': (head, None),
        'convolutions-only': ([], ['Conv', 'ConvTranspose']),
    }
    for k in (1, 6, 60):
        found[f'first-{k}-only'] = (names[k:], None)
    for k in (20, 60):
        found[f'all-but-first-{k}'] = (names[:k], None)
    return found


def frames(town):
    paths = sorted(glob.glob(f'{town}/loop/sequence/*'))[::3]
    for condition in ('deep_night', 'dense_fog', 'rain_fog', 'sunset_glare'):
        paths += sorted(glob.glob(f'{town}/{condition}/query/*'))[::6]
    return paths


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('models_dir')
    parser.add_argument('town_dev')
    parser.add_argument('--variants', help='comma-separated names (default: every one)')
    parser.add_argument('--ranges', help='ranges table (default: tools/quantization/ppocrv5_det.ranges.json)')
    args = parser.parse_args()
    fp32_path = os.path.join(args.models_dir, 'ocr', 'ppocrv5_det.onnx')
    table_path = args.ranges or os.path.join(os.path.dirname(os.path.abspath(__file__)), 'quantization',
                                             'ppocrv5_det.ranges.json')
    paths = frames(args.town_dev)
    if not paths:
        sys.exit(f'no town-dev frames under {args.town_dev}')
    inputs = [qm.detector_input(Image.open(p)) for p in paths]
    fp32 = mq.session(fp32_path)
    reference = [mq.run(fp32, x)[0][0, 0] > TEXT for x in inputs]
    with tempfile.TemporaryDirectory(prefix='humem-sweep.') as tmp:
        pre = os.path.join(tmp, 'pre.onnx')
        qm.preprocess(fp32_path, pre)
        table_variants = variants([n.name for n in onnx.load(pre).graph.node])
        chosen = args.variants.split(',') if args.variants else list(table_variants)
        print(f'{len(paths)} frames; variant, text pixels kept, agree')
        for name in chosen:
            exclude, op_types = table_variants[name]
            table = qm.read_table(table_path)
            table['quantization']['exclude'] = exclude
            if op_types:
                table['quantization']['op_types'] = op_types
            model = qm.qdq_model(pre, table)
            del model.model.graph.value_info[:]
            out = os.path.join(tmp, f'{name}.onnx')
            model.save_model_to_file(out)
            int8 = mq.session(out)
            marked = kept = both = 0
            for x, ref in zip(inputs, reference):
                got = mq.run(int8, x)[0][0, 0] > TEXT
                marked, kept, both = marked + int(ref.sum()), kept + int((ref & got).sum()), both + int(got.sum())
            print(f'{name:22s} {kept / max(1, marked):.2f} {kept / max(1, both):.2f}', flush=True)


if __name__ == '__main__':
    main()
