#!/usr/bin/env python3
"""How the int8 models of tools/quantize_models.py compare with the fp32 ones: speed and accuracy.

    measure_quantized.py MODELS_DIR [--runs N] [--json OUT]

For each model, ONNX Runtime on one thread (intra_op_num_threads=1), batch 1, at HuMem's input
sizes (descriptor 384x288, detector 512x288, recogniser 48 high x about 200), fp32 and int8 runs
interleaved so a busy machine slows both alike; the median latency of each and their ratio. Then
accuracy proxies on pictures that were not used for calibration (other seeds, mirrored crops):
  efficientnet  descriptor cosine fp32 vs int8 (min, mean), scene top-1 agreement; also on the
                whole sample pictures, which are in the calibration set;
  detector      probability map mean |fp32 - int8|, text box count agreement (DB post-processing
                as crates/perception/src/ocr/db.rs, on axis-aligned component bounds);
  recogniser    greedy CTC strings: int8 == fp32, and each == the rendered text.
Needs the models and venv of scripts/setup-models.sh, int8 files included.
"""
import argparse
import glob
import json
import os
import statistics
import sys
import time

import numpy as np
import onnxruntime as ort
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import quantize_models as qm  # noqa: E402

EVAL_SEED = 7  # not the calibration seed
FILES = {
    'efficientnet_lite0': 'efficientnet-lite0/efficientnet_lite0',
    'ppocrv5_det': 'ocr/ppocrv5_det',
    'ppocrv5_rec': 'ocr/ppocrv5_rec',
}
DB_THRESHOLD, DB_BOX_THRESHOLD, DB_MIN_SIZE = 0.3, 0.6, 3


def session(path, threads=1):
    """A CPU session. Without VNNI, ONNX Runtime's uint8 x int8 kernels (AVX2 vpmaddubsw) saturate
    and the int8 models lose much of their accuracy, so there it takes the exact, slower uint8 x
    uint8 path (session.x64quantprecision; with VNNI that option changes no result, only slows)."""
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = threads, 1
    options.log_severity_level = 3
    if not qm.has_vnni():
        options.add_session_config_entry('session.x64quantprecision', '1')
    return ort.InferenceSession(path, options, providers=['CPUExecutionProvider'])


def pair(models_dir, name, threads=1):
    """(fp32, int8) sessions of a model."""
    base = os.path.join(models_dir, FILES[name])
    return session(base + '.onnx', threads), session(base + '.int8.onnx', threads)


def run(sess, x):
    return sess.run(None, {sess.get_inputs()[0].name: x})


def latencies(sessions, x, runs):
    """Median milliseconds of each session on `x`, runs interleaved after a warm-up."""
    for s in sessions:
        for _ in range(3):
            run(s, x)
    times = [[] for _ in sessions]
    for _ in range(runs):
        for s, t in zip(sessions, times):
            start = time.perf_counter()
            run(s, x)
            t.append((time.perf_counter() - start) * 1000)
    return [statistics.median(t) for t in times]


# --- efficientnet -------------------------------------------------------------------------------

def efficientnet_eval_inputs(pictures, mean, std, seed=EVAL_SEED):
    """(whole sample pictures, held-out: mirrored random crops and text scenes of another seed)."""
    rng = np.random.default_rng(seed)
    whole = [qm.efficientnet_input(p, mean, std) for _, p in pictures]
    held = [qm.random_crop(rng, p, 4 / 3).transpose(Image.Transpose.FLIP_LEFT_RIGHT) for _, p in pictures]
    held += [qm.text_scene(rng, pictures[int(rng.integers(len(pictures)))][1], qm.EFF_SIZE) for _ in range(16)]
    return whole, [qm.efficientnet_input(p, mean, std) for p in held]


def descriptor_agreement(fp32, int8, inputs):
    """Descriptor cosine of int8 vs fp32 (min, mean) and scene top-1 agreement, over all inputs
    and over those where fp32's top-1 has p >= 0.5."""
    cos, same, confident = [], [], []
    for x in inputs:
        (d0, s0), (d1, s1) = run(fp32, x), run(int8, x)
        cos.append(float(d0[0] @ d1[0] / np.linalg.norm(d0[0]) / np.linalg.norm(d1[0])))
        same.append(int(s0.argmax()) == int(s1.argmax()))
        if s0.max() >= 0.5:
            confident.append(same[-1])
    return {'cos_min': min(cos), 'cos_mean': statistics.fmean(cos), 'top1': statistics.fmean(same),
            'top1_confident': statistics.fmean(confident) if confident else None, 'confident': len(confident)}


def measure_efficientnet(models_dir, pictures, runs):
    fp32, int8 = pair(models_dir, 'efficientnet_lite0')
    meta = fp32.get_modelmeta().custom_metadata_map
    mean, std = ([float(v) for v in meta[k].split(',')] for k in ('humem.mean', 'humem.std'))
    whole, held = efficientnet_eval_inputs(pictures, mean, std)
    ms = latencies((fp32, int8), whole[0], runs)
    return {'ms': ms, 'samples': descriptor_agreement(fp32, int8, whole),
            'held_out': descriptor_agreement(fp32, int8, held)}


# --- detector -----------------------------------------------------------------------------------

def components(mask):
    """Bounds (x0, y0, x1, y1) inclusive of the 8-connected regions of a boolean map."""
    seen = np.zeros_like(mask)
    h, w = mask.shape
    found = []
    for y0, x0 in zip(*np.nonzero(mask)):
        if seen[y0, x0]:
            continue
        seen[y0, x0] = True
        stack, xs, ys = [(y0, x0)], [], []
        while stack:
            y, x = stack.pop()
            xs.append(x)
            ys.append(y)
            for ny in range(max(0, y - 1), min(h, y + 2)):
                for nx in range(max(0, x - 1), min(w, x + 2)):
                    if mask[ny, nx] and not seen[ny, nx]:
                        seen[ny, nx] = True
                        stack.append((ny, nx))
        found.append((min(xs), min(ys), max(xs), max(ys)))
    return found


def text_boxes(prob):
    """DBNet boxes of a [H, W] probability map: components above 0.3 whose short side is at
    least 3 and whose mean probability is at least 0.6 (axis-aligned, not min-area rectangles)."""
    boxes = []
    for x0, y0, x1, y1 in components(prob > DB_THRESHOLD):
        if min(x1 - x0 + 1, y1 - y0 + 1) < DB_MIN_SIZE:
            continue
        if prob[y0:y1 + 1, x0:x1 + 1].mean() >= DB_BOX_THRESHOLD:
            boxes.append((x0, y0, x1, y1))
    return boxes


def measure_detector(models_dir, pictures, runs):
    fp32, int8 = pair(models_dir, 'ppocrv5_det')
    rng = np.random.default_rng(EVAL_SEED)
    scenes = [qm.detector_input(s) for _, s in qm.detector_scenes(pictures, rng, 40)]
    ms = latencies((fp32, int8), scenes[0], runs)
    diffs, same, boxes32, boxes8, matched = [], [], 0, 0, 0
    for x in scenes:
        p0, p1 = run(fp32, x)[0][0, 0], run(int8, x)[0][0, 0]
        diffs.append(float(np.abs(p0 - p1).mean()))
        b0, b1 = text_boxes(p0), text_boxes(p1)
        same.append(len(b0) == len(b1))
        boxes32, boxes8 = boxes32 + len(b0), boxes8 + len(b1)
        matched += sum(any(iou(a, b) >= 0.5 for b in b1) for a in b0)
    return {'ms': ms, 'prob_mad_mean': statistics.fmean(diffs), 'prob_mad_max': max(diffs),
            'box_count_agreement': statistics.fmean(same), 'boxes_fp32': boxes32, 'boxes_int8': boxes8,
            'fp32_boxes_matched': matched / max(1, boxes32)}


def iou(a, b):
    """Intersection over union of two inclusive pixel boxes (x0, y0, x1, y1)."""
    w = min(a[2], b[2]) - max(a[0], b[0]) + 1
    h = min(a[3], b[3]) - max(a[1], b[1]) + 1
    if w <= 0 or h <= 0:
        return 0.0
    area = lambda r: (r[2] - r[0] + 1) * (r[3] - r[1] + 1)  # noqa: E731
    return w * h / (area(a) + area(b) - w * h)


# --- recogniser ---------------------------------------------------------------------------------

def dictionary(models_dir):
    """The recogniser's classes: line i of ppocr_keys_v5.txt (0 is the CTC blank), untrimmed."""
    with open(os.path.join(models_dir, 'ocr', 'ppocr_keys_v5.txt'), encoding='utf-8') as f:
        text = f.read().removeprefix('\ufeff').removesuffix('\n')
    return [line.removesuffix('\r') for line in text.split('\n')]


def ctc_decode(probs, entries):
    """Greedy CTC of one [T, C] sequence, as crates/perception/src/ocr/ctc.rs: (text, confidence)."""
    best = probs.argmax(axis=1)
    keep = (best != 0) & np.concatenate([[True], best[1:] != best[:-1]])
    text = ''.join(entries[c] for c in best[keep]).strip()
    return text, float(probs[keep, best[keep]].mean()) if text else 0.0


def rendered_lines(pictures, count, seed=EVAL_SEED):
    """[(text, recogniser input)] of `count` rendered lines."""
    rng = np.random.default_rng(seed)
    lines = (qm.text_line(rng, pictures) for _ in range(count))
    return [(text, qm.recognizer_input(line)) for line, text in lines]


def readings(fp32, int8, lines, entries):
    """[(truth, fp32 text, int8 text)] of rendered lines."""
    return [(truth, *(ctc_decode(run(s, x)[0][0], entries)[0] for s in (fp32, int8))) for truth, x in lines]


def reading_agreement(read):
    """Fractions of lines where int8 reads as fp32, fp32 reads the truth, int8 reads the truth."""
    return tuple(statistics.fmean(ok) for ok in zip(*((t0 == t1, t0 == t, t1 == t) for t, t0, t1 in read)))


def measure_recognizer(models_dir, pictures, runs):
    fp32, int8 = pair(models_dir, 'ppocrv5_rec')
    lines = rendered_lines(pictures, 100)
    x = np.zeros((1, 3, qm.REC_HEIGHT, 200), np.float32)  # the first line, cut or padded to 200 wide
    first = lines[0][1][..., :200]
    x[..., :first.shape[-1]] = first
    ms = latencies((fp32, int8), x, runs)
    read = readings(fp32, int8, lines, dictionary(models_dir))
    agree, right32, right8 = reading_agreement(read)
    return {'ms': ms, 'lines': len(lines), 'int8_equals_fp32': agree, 'fp32_correct': right32,
            'int8_correct': right8, 'differences': [r for r in read if r[1] != r[2]]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('models_dir')
    ap.add_argument('--runs', type=int, default=40)
    ap.add_argument('--json')
    args = ap.parse_args()
    (wheel,) = glob.glob(os.path.join(args.models_dir, 'testdata', 'scikit_image-*.whl'))
    pictures = qm.sample_pictures(wheel)
    results = {'efficientnet_lite0': measure_efficientnet(args.models_dir, pictures, args.runs),
               'ppocrv5_det': measure_detector(args.models_dir, pictures, args.runs),
               'ppocrv5_rec': measure_recognizer(args.models_dir, pictures, args.runs)}
    print(f'onnxruntime {ort.__version__}, CPU with VNNI: {qm.has_vnni()}')
    for name, r in results.items():
        fp, q = r.pop('ms')
        print(f'{name}: fp32 {fp:.2f} ms, int8 {q:.2f} ms, int8/fp32 {q / fp:.2f}; '
              + json.dumps(r, default=lambda v: round(v, 4)))
        r['ms'] = {'fp32': fp, 'int8': q}
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(results, f, indent=1)


if __name__ == '__main__':
    main()
