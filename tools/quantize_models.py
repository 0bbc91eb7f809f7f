#!/usr/bin/env python3
"""Int8 versions of HuMem's ONNX models, made with ONNX Runtime's static QDQ quantisation.

    quantize_models.py calibrate MODELS_DIR SKIMAGE_WHEEL OUT_DIR
    quantize_models.py quantize FP32_MODEL RANGES_JSON OUT_INT8

The models are EfficientNet-Lite0 (descriptor and scene), the PP-OCRv5 mobile text detector
(DBNet) and the PP-OCRv5 mobile line recogniser (CTC). Static quantisation needs the range of
every activation, measured by running the fp32 model on calibration pictures. Those ranges are
floats computed by ONNX Runtime, and they differ by a few ulps between CPUs (AVX2 and AVX-512
kernels sum in different orders), which would change the int8 file and so its sha256. The work is
therefore split in two:

- `calibrate` runs the fp32 models on the calibration pictures and writes one human-readable
  table per model, OUT_DIR/<model>.ranges.json: tensor name -> [low, high], rounded to 6
  significant digits, with how they were measured and the quantisation settings. The tables
  are committed (tools/quantization/); re-run this only when a model or the settings change.
- `quantize` is pure arithmetic on the fp32 model and one table (ONNX Runtime's own
  QDQQuantizer, as quantize_static uses it after calibrating), so its output is the same bytes
  everywhere, and scripts/setup-models.sh pins its sha256.

Both steps first run quant_pre_process (ONNX Runtime's basic graph optimisations: BatchNorm folded
into convolutions, Identity nodes dropped; no symbolic shape inference, which needs sympy), so the
table's tensor names are those of the model the quantizer sees.

Calibration pictures never come from an evaluation data set: they are scikit-image's sample
pictures (from the scikit-image wheel setup-models.sh keeps) and text that Pillow renders with
its built-in TrueType font (signs pasted onto those pictures, and text lines), with fixed seeds.
Each model gets its input the way HuMem prepares it (crates/perception): EfficientNet RGB at
384x288; the detector BGR, long side 512, padded to multiples of 32; the recogniser BGR lines
48 pixels high, contrast stretched, at most 480 wide.
"""
import argparse
import contextlib
import hashlib
import io
import json
import os
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnxruntime.quantization import QuantType
from onnxruntime.quantization.calibrate import (CalibrationDataReader, CalibrationMethod, TensorData,
                                                TensorsData, create_calibrator)
from onnxruntime.quantization.qdq_quantizer import QDQQuantizer
from onnxruntime.quantization.quant_utils import load_model_with_shape_infer
from onnxruntime.quantization.shape_inference import quant_pre_process
from PIL import Image, ImageDraw, ImageFont

ort.set_default_logger_severity(3)  # quant_pre_process's sessions warn about the OCR models' output shapes

FORMAT = 1
QDQ_OPSET = 13
SIGNIFICANT = 6  # digits kept of each range bound
CALIBRATION_SEED = 20240601
EFF_SIZE = (384, 288)  # width, height: HuMem's descriptor input
DET_LONG_SIDE, DET_STRIDE = 512, 32
DET_MEAN, DET_STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
REC_HEIGHT, REC_MAX_WIDTH = 48, 480

# Where each model lives under MODELS_DIR, how its ranges are measured and which op types get
# Q/DQ pairs (nodes in `exclude` stay float). Weights are QInt8 per output channel (per tensor
# loses too much), activations QUInt8: ONNX Runtime's fast x86 kernels, exact on CPUs with VNNI
# (without it, sessions need session.x64quantprecision=1). The choices are measured, see
# tools/README.md: the Percentile calibrator (the 99.99th percentile, not the extreme) suits the
# convolutional models, whose activations have long tails; the recogniser's final classifier
# needs MinMax. Quantising the recogniser's elementwise Add/Mul (its learnable affine blocks)
# halves its agreement with fp32, so they stay float, as do its attention products (no gain);
# the detector keeps its accuracy with them quantised, and runs faster.
PERCENTILE = {'method': 'Percentile', 'options': {'percentile': 99.99, 'symmetric': False}}
MODELS = {
    'efficientnet_lite0': {
        'path': 'efficientnet-lite0/efficientnet_lite0.onnx',
        'calibration': PERCENTILE,
        'op_types': ['Conv', 'Clip'],
        'exclude': [],
    },
    'ppocrv5_det': {
        'path': 'ocr/ppocrv5_det.onnx',
        'calibration': PERCENTILE,
        'op_types': ['Conv', 'ConvTranspose', 'Relu', 'Add', 'Mul', 'Resize', 'Concat', 'GlobalAveragePool'],
        'exclude': [],
    },
    'ppocrv5_rec': {
        'path': 'ocr/ppocrv5_rec.onnx',
        'calibration': {'method': 'MinMax', 'options': {}},
        'op_types': ['Conv', 'MatMul'],
        'exclude': ['MatMul.1', 'MatMul.2', 'MatMul.7', 'MatMul.8'],  # attention: q.k^T, softmax.v
    },
}
SETTINGS = {'activation_type': 'QUInt8', 'weight_type': 'QInt8', 'per_channel': True}

WORDS = ('EXIT', 'Exit', 'ENTRANCE', 'Entrance', 'OPEN', 'Closed', 'PUSH', 'PULL', 'Room', 'Office',
         'Kitchen', 'Library', 'Lab', 'Stairs', 'Lift', 'Toilets', 'Reception', 'Platform', 'Gate',
         'Station', 'Street', 'Road', 'Avenue', 'Main St', 'Car Park', 'No Parking', 'No Smoking',
         'Fire Door', 'Keep Clear', 'Staff Only', 'Meeting Room', 'Floor', 'Level', 'Wing', 'North',
         'South', 'East', 'West', 'Cafe', 'Pharmacy', 'Bakery', 'Books', 'Hotel', 'Museum', 'Hall',
         'Welcome', 'Information', 'Tickets', 'Departures', 'Arrivals', 'Bus', 'Taxi', 'Bicycles',
         'Warehouse', 'Loading Bay', 'Server', 'Storage', 'Danger', 'Caution', 'Wet Floor', 'Quiet',
         'Shop', 'Market', 'Garden', 'Park', 'Bridge', 'Tower', 'Block', 'Unit', 'Aisle', 'Zone')


# --- calibration pictures -------------------------------------------------------------------

def sample_pictures(wheel):
    """scikit-image's sample pictures, (name, RGB image), sorted by name."""
    with zipfile.ZipFile(wheel) as z:
        names = sorted(n for n in z.namelist()
                       if n.startswith('skimage/data/') and n.endswith(('.png', '.jpg')))
        return [(os.path.basename(n), Image.open(io.BytesIO(z.read(n))).convert('RGB')) for n in names]


def random_text(rng):
    """A sign's text: one to three words, sometimes with a number."""
    words = [WORDS[i] for i in rng.integers(len(WORDS), size=rng.integers(1, 4))]
    if rng.random() < 0.4:
        if rng.random() < 0.7:
            number = str(rng.integers(1, 999))
        else:
            number = f'{chr(65 + rng.integers(26))}{rng.integers(1, 99)}'
        words.insert(int(rng.integers(len(words) + 1)), number)
    text = ' '.join(words)
    return text.upper() if rng.random() < 0.25 else text


def contrasting_colours(rng):
    """(ink, paper) RGB colours whose luma differs by at least 90."""
    while True:
        ink, paper = (tuple(int(v) for v in rng.integers(0, 256, 3)) for _ in range(2))
        if abs(luma(ink) - luma(paper)) >= 90:
            return ink, paper


def luma(rgb):
    """ITU-R 601 luma in fixed point, as Pillow's convert('L') and crates/perception's luma."""
    r, g, b = rgb
    return (r * 19595 + g * 38470 + b * 7471 + 0x8000) >> 16


def render_text(rng, text, size, background=None):
    """`text` at font `size` with margins, on a plain colour or on `background` (an RGB picture
    cropped to fit), as an RGB image."""
    font = ImageFont.load_default(size=size)
    ink, paper = contrasting_colours(rng)
    stroke = int(rng.random() < 0.3)
    left, top, right, bottom = font.getbbox(text, stroke_width=stroke)
    mx, my = (int(size * f) for f in rng.uniform(0.2, 0.6, 2))
    w, h = right - left + 2 * mx, bottom - top + 2 * my
    if background is None:
        image = Image.new('RGB', (w, h), paper)
    else:
        image = random_crop(rng, background, w / h).resize((w, h), Image.BILINEAR)
        ink = (0, 0, 0) if luma(image.resize((1, 1), Image.BOX).getpixel((0, 0))) > 127 else (255, 255, 255)
    ImageDraw.Draw(image).text((mx - left, my - top), text, font=font, fill=ink, stroke_width=stroke,
                               stroke_fill=ink)
    return image


def random_crop(rng, picture, aspect):
    """A random crop of `picture` with width / height `aspect`, at least a third of it across."""
    pw, ph = picture.size
    w = min(pw, ph * aspect) * rng.uniform(0.35, 1.0)
    w, h = max(1, int(w)), max(1, int(w / aspect))
    x, y = int(rng.integers(0, pw - w + 1)), int(rng.integers(0, ph - h + 1))
    return picture.crop((x, y, x + w, y + h))


def text_scene(rng, picture, size):
    """A random crop of `picture` at `size` with up to seven signs pasted on it, apart, some tilted."""
    scene = random_crop(rng, picture, size[0] / size[1]).resize(size, Image.BILINEAR)
    placed = []
    for _ in range(int(rng.integers(2, 8))):
        sign = render_text(rng, random_text(rng), int(rng.integers(12, 44)))
        if rng.random() < 0.3:
            sign = sign.rotate(float(rng.uniform(-12, 12)), Image.BILINEAR, expand=True,
                               fillcolor=sign.getpixel((0, 0)))
        box = free_place(rng, sign.size, size, placed)
        if box is not None:
            scene.paste(sign, box[:2])
            placed.append(box)
    return scene


def free_place(rng, sign, scene, placed, tries=10):
    """A box (x0, y0, x1, y1) for a `sign`-sized image inside `scene` off the `placed` boxes."""
    if sign[0] >= scene[0] or sign[1] >= scene[1]:
        return None
    for _ in range(tries):
        x, y = int(rng.integers(0, scene[0] - sign[0])), int(rng.integers(0, scene[1] - sign[1]))
        box = (x, y, x + sign[0], y + sign[1])
        if all(box[2] <= b[0] or b[2] <= box[0] or box[3] <= b[1] or b[3] <= box[1] for b in placed):
            return box
    return None


def text_line(rng, pictures):
    """(image, text) of one rendered text line, on a plain colour or on a sample picture."""
    text = random_text(rng)
    background = pictures[int(rng.integers(len(pictures)))][1] if rng.random() < 0.3 else None
    return render_text(rng, text, int(rng.integers(14, 60)), background), text


# --- model inputs, as HuMem prepares them -----------------------------------------------------

def efficientnet_input(image, mean, std, size=EFF_SIZE):
    """[1, 3, 288, 384] (`size` is width, height) RGB, x / 255 normalised with the model's
    humem.mean / humem.std (tools/reference_descriptor.py)."""
    rgb = np.asarray(image.convert('RGB').resize(size, Image.BILINEAR), np.float32) / 255
    return ((rgb - np.float32(mean)) / np.float32(std)).transpose(2, 0, 1)[None].astype(np.float32)


def detector_input(image, long_side=DET_LONG_SIDE):
    """[1, 3, H, W]: long side scaled to `long_side`, BGR planes normalised with the ImageNet mean
    and deviation in PaddleOCR's order (plane i with mean[i]), zero-padded to multiples of 32
    (crates/perception/src/ocr/canvas.rs)."""
    scale = long_side / max(image.size)
    fw, fh = (min(long_side, max(1, int(s * scale + 0.5))) for s in image.size)  # Rust's f32::round
    rgb = np.asarray(image.convert('RGB').resize((fw, fh), Image.BILINEAR), np.float32) / 255
    planes = [(rgb[..., 2 - i] - np.float32(DET_MEAN[i])) / np.float32(DET_STD[i]) for i in range(3)]
    x = np.zeros((1, 3, -(-fh // DET_STRIDE) * DET_STRIDE, -(-fw // DET_STRIDE) * DET_STRIDE), np.float32)
    x[0, :, :fh, :fw] = planes
    return x


def stretch_contrast(image, low=0.02, high=0.98):
    """The luma levels at the `low` and `high` fractions to 0 and 255, as crates/perception's
    stretch_contrast; nearly flat images (span under 8) are left alone."""
    histogram = np.bincount(np.asarray(image.convert('L')).ravel(), minlength=256)
    seen = np.cumsum(histogram)
    total = image.width * image.height
    lo, hi = (float(np.argmax(seen > max(0.0, f * total))) for f in (low, high))
    if hi - lo < 8:
        return image
    v = (np.asarray(image, np.float32) - lo) * (255 / (hi - lo))
    return Image.fromarray(np.clip(np.round(v), 0, 255).astype(np.uint8))


def recognizer_input(line, height=REC_HEIGHT, max_width=REC_MAX_WIDTH):
    """[1, 3, 48, W]: the line contrast stretched, turned if it stands, scaled to 48 high keeping
    its aspect (24 <= W <= 480), BGR, (v / 255 - 0.5) / 0.5 (line_input in ocr/mod.rs)."""
    line = stretch_contrast(line.convert('RGB'))
    if line.height >= 1.5 * line.width:
        line = line.transpose(Image.Transpose.ROTATE_90)
    width = min(max(int(height * line.width / max(1, line.height) + 0.5), height // 2), max_width)
    rgb = np.asarray(line.resize((width, height), Image.BILINEAR), np.float32) / 255
    return ((rgb[..., ::-1] - 0.5) / 0.5).transpose(2, 0, 1)[None].astype(np.float32)


def model_metadata(path):
    with open(path, 'rb') as f:
        return {p.key: p.value for p in onnx.load_model(f, load_external_data=False).metadata_props}


def efficientnet_inputs(pictures, rng, mean, std):
    """Each sample picture whole, a random crop of each, and 16 text scenes."""
    images = [(name, p) for name, p in pictures]
    images += [(f'{name} crop', random_crop(rng, p, EFF_SIZE[0] / EFF_SIZE[1])) for name, p in pictures]
    images += [(f'text scene {i}', text_scene(rng, pictures[int(rng.integers(len(pictures)))][1], EFF_SIZE))
               for i in range(16)]
    return [(label, efficientnet_input(image, mean, std)) for label, image in images]


def detector_scenes(pictures, rng, count):
    """`count` text scenes at 512x288 on random sample pictures."""
    return [(f'text scene {i}', text_scene(rng, pictures[int(rng.integers(len(pictures)))][1], (512, 288)))
            for i in range(count)]


def detector_inputs(pictures, rng):
    """Each sample picture whole (its own aspect) and 40 text scenes at 512x288."""
    images = list(pictures) + detector_scenes(pictures, rng, 40)
    return [(label, detector_input(image)) for label, image in images]


def recognizer_inputs(pictures, rng, count=160):
    """`count` rendered text lines."""
    return [(f'line {text!r}', recognizer_input(line))
            for line, text in (text_line(rng, pictures) for _ in range(count))]


def calibration_inputs(name, fp32_path, pictures, seed=CALIBRATION_SEED):
    """[(label, input tensor)] for model `name`, deterministic for a seed."""
    rng = np.random.default_rng(seed)
    if name == 'efficientnet_lite0':
        meta = model_metadata(fp32_path)
        mean, std = ([float(v) for v in meta[k].split(',')] for k in ('humem.mean', 'humem.std'))
        return efficientnet_inputs(pictures, rng, mean, std)
    if name == 'ppocrv5_det':
        return detector_inputs(pictures, rng)
    return recognizer_inputs(pictures, rng)


# --- calibrate ----------------------------------------------------------------------------------

def has_vnni():
    """Whether this x86 CPU has VNNI (AVX512-VNNI or AVX-VNNI), where ONNX Runtime's fast
    uint8 x int8 kernels are exact."""
    try:
        with open('/proc/cpuinfo') as f:
            flags = set(f.read().split())
    except OSError:
        return False
    return bool(flags & {'avx512_vnni', 'avx_vnni'})


def sha256_file(path):
    with open(path, 'rb') as f:
        return hashlib.sha256(f.read()).hexdigest()


def preprocess(fp32_path, out_path):
    """ONNX Runtime's quant_pre_process, without symbolic shape inference (needs sympy), after
    raising the opset to 13 where it is lower (per-channel DequantizeLinear needs 13)."""
    model = onnx.load(fp32_path)
    if opset(model) < QDQ_OPSET:
        fp32_path = out_path + '.opset13.onnx'
        onnx.save(onnx.version_converter.convert_version(model, QDQ_OPSET), fp32_path)
    quant_pre_process(fp32_path, out_path, skip_symbolic_shape=True)


def opset(model):
    return next(o.version for o in model.opset_import if o.domain in ('', 'ai.onnx'))


class Reader(CalibrationDataReader):
    def __init__(self, input_name, tensors):
        self.feeds = iter([{input_name: t} for t in tensors])

    def get_next(self):
        return next(self.feeds, None)


def measure_ranges(model_path, op_types, tensors, calibration):
    """{tensor name: (low, high)} of the inputs and outputs of the model's `op_types` nodes over
    the calibration inputs, by ONNX Runtime's calibrator (`calibration`: method and options)."""
    with tempfile.TemporaryDirectory(prefix='humem-calib.') as tmp, contextlib.redirect_stdout(io.StringIO()):
        calibrator = create_calibrator(model_path, op_types, os.path.join(tmp, 'augmented.onnx'),
                                       calibrate_method=CalibrationMethod[calibration['method']],
                                       providers=['CPUExecutionProvider'], extra_options=calibration['options'])
        input_name = calibrator.model.graph.input[0].name
        for t in tensors:  # one at a time: inputs differ in shape, which histograms cannot stack
            calibrator.collect_data(Reader(input_name, [t]))
        ranges = calibrator.compute_data()
    return {name: tuple(float(np.asarray(v).item()) for v in td.range_value) for name, td in ranges.items()}


def rounded(value):
    return float(f'{value:.{SIGNIFICANT}g}')


def inputs_digest(tensors):
    """sha256 over the calibration tensors' shapes and float32 bytes."""
    h = hashlib.sha256()
    for t in tensors:
        h.update(str(t.shape).encode())
        h.update(np.ascontiguousarray(t, np.float32).tobytes())
    return h.hexdigest()


def ranges_table(name, fp32_path, labels, tensors, ranges):
    """The JSON table of one model's ranges and how they were made."""
    return {
        'format': FORMAT,
        'model': name,
        'model_sha256': sha256_file(fp32_path),
        'calibration': {
            **MODELS[name]['calibration'],
            'onnxruntime': ort.__version__,
            'seed': CALIBRATION_SEED,
            'inputs': len(tensors),
            'inputs_sha256': inputs_digest(tensors),
            'images': labels,
        },
        'quantization': dict(SETTINGS, op_types=MODELS[name]['op_types'], exclude=MODELS[name]['exclude']),
        'ranges': {k: [rounded(lo), rounded(hi)] for k, (lo, hi) in sorted(ranges.items())},
    }


def write_table(table, path):
    """JSON with one line per range, so a diff shows which tensors moved."""
    body = json.dumps({k: v for k, v in table.items() if k != 'ranges'}, indent=1)
    ranges = ',\n'.join(f'  {json.dumps(k)}: {json.dumps(v)}' for k, v in table['ranges'].items())
    with open(path, 'w') as f:
        f.write(body[:-2] + ',\n "ranges": {\n' + ranges + '\n }\n}\n')


def calibrate_model(name, models_dir, pictures, out_dir):
    fp32 = os.path.join(models_dir, MODELS[name]['path'])
    labelled = calibration_inputs(name, fp32, pictures)
    labels, tensors = [label for label, _ in labelled], [t for _, t in labelled]
    with tempfile.TemporaryDirectory(prefix='humem-quant.') as tmp:
        pre = os.path.join(tmp, 'pre.onnx')
        preprocess(fp32, pre)
        ranges = measure_ranges(pre, MODELS[name]['op_types'], tensors, MODELS[name]['calibration'])
    path = os.path.join(out_dir, f'{name}.ranges.json')
    write_table(ranges_table(name, fp32, labels, tensors, ranges), path)
    print(f'wrote {path}: {len(ranges)} tensors from {len(tensors)} inputs')


def calibrate(models_dir, wheel, out_dir, names=tuple(MODELS)):
    os.makedirs(out_dir, exist_ok=True)
    pictures = sample_pictures(wheel)
    for name in names:
        calibrate_model(name, models_dir, pictures, out_dir)


# --- quantize -----------------------------------------------------------------------------------

def read_table(path):
    with open(path) as f:
        table = json.load(f)
    if table.get('format') != FORMAT:
        raise ValueError(f'{path}: not a ranges table of format {FORMAT}')
    return table


def tensors_data(table):
    """The table's ranges as the TensorsData quantize_static builds from a calibrator."""
    return TensorsData(CalibrationMethod.MinMax, {
        k: TensorData(lowest=np.float32(lo), highest=np.float32(hi)) for k, (lo, hi) in table['ranges'].items()})


def qdq_model(pre_path, table):
    """The preprocessed model quantised from the table's ranges, as quantize_static does it
    (an onnxruntime.quantization ONNXModel)."""
    q = table['quantization']
    quantizer = QDQQuantizer(
        load_model_with_shape_infer(Path(pre_path)), q['per_channel'], False,
        getattr(QuantType, q['weight_type']), getattr(QuantType, q['activation_type']),
        tensors_data(table), [], q['exclude'], q['op_types'], {})
    quantizer.quantize_model()
    return quantizer.model


def set_metadata(model, fp32_path, fp32_sha, ranges_sha):
    """humem.* metadata of the fp32 model, plus humem.precision and what the model came from."""
    props = {k: v for k, v in model_metadata(fp32_path).items() if k.startswith('humem.')}
    props.update({'humem.precision': 'int8',
                  'humem.quantized_from': f'{os.path.basename(fp32_path)} sha256={fp32_sha}',
                  'humem.quantization_ranges': f'sha256={ranges_sha}'})
    del model.metadata_props[:]
    onnx.helper.set_model_props(model, dict(sorted(props.items())))


def quantize(fp32_path, ranges_path, out_path):
    table = read_table(ranges_path)
    fp32_sha = sha256_file(fp32_path)
    if fp32_sha != table['model_sha256']:
        sys.exit(f'{fp32_path} has sha256 {fp32_sha}, but {ranges_path} was calibrated on '
                 f'{table["model_sha256"]}: re-run `calibrate`')
    with tempfile.TemporaryDirectory(prefix='humem-quant.') as tmp:
        pre = os.path.join(tmp, 'pre.onnx')
        preprocess(fp32_path, pre)
        model = qdq_model(pre, table)
    set_metadata(model.model, fp32_path, fp32_sha, sha256_file(ranges_path))
    del model.model.graph.value_info[:]  # shape hints of the fp32 graph, some rank-less; ORT infers its own
    model.save_model_to_file(out_path)
    print(f'wrote {out_path}: sha256 {sha256_file(out_path)}')


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    sub = ap.add_subparsers(dest='command', required=True)
    c = sub.add_parser('calibrate', help='measure activation ranges, write OUT_DIR/<model>.ranges.json')
    c.add_argument('models_dir')
    c.add_argument('skimage_wheel')
    c.add_argument('out_dir')
    c.add_argument('--model', action='append', choices=list(MODELS), help='only this model (repeatable)')
    q = sub.add_parser('quantize', help='build the int8 QDQ model from a committed ranges table')
    q.add_argument('fp32_model')
    q.add_argument('ranges_json')
    q.add_argument('out_int8')
    args = ap.parse_args()
    if args.command == 'calibrate':
        calibrate(args.models_dir, args.skimage_wheel, args.out_dir, args.model or tuple(MODELS))
    else:
        quantize(args.fp32_model, args.ranges_json, args.out_int8)


if __name__ == '__main__':
    main()
