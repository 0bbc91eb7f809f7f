#!/usr/bin/env python3
"""Does PCA-whitening help the global descriptor? Descriptor-only R@1 on
every dev data set, without and with whitening.

    whitening_probe.py [DATASETS_DIR] [MODEL]

(defaults ../shared/datasets, models/efficientnet-lite0/efficientnet_lite0.onnx)

Descriptors are the server's (tools/reference_descriptor.py at 384x288, which
the fidelity test holds to cosine >= 0.999 of the server's). R@1 is the
nearest stored image by cosine: the reference images of a `pairs` set, the
frames at least `min_frame_gap` earlier of a `loop` set. Whitening is fitted
two ways: on the set's own store (the references, or the whole sequence),
as a server would fit it on its keyframes; and leave-one-out, on the stores
of the other sets (the town-dev conditions share one reference drive, so
they leave each other out). Variants: centring only; PCA to d dimensions
with each eigenvalue regularised by `shrink` times their mean and raised to
`-power` (0.5 is whitening proper). docs/evaluation.md ("Perception quality")
quotes the result.
"""
import glob
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from reference_descriptor import describer  # noqa: E402

SETS = ['corridor', 'gardens-daynight', 'rtabmap-loop', 'town-dev/loop', 'town-dev/deep_night',
        'town-dev/dense_fog', 'town-dev/rain_fog', 'town-dev/sunset_glare']
VARIANTS = [('none', None), ('centre', (0, 0, 0))] + [
    (f'd{d} shrink {s} power {p}', (d, s, p)) for d in (64, 256) for s in (0.1, 1.0) for p in (0.25, 0.5)]


def fit(store, dims, shrink, power):
    """The whitening learned on `store` (rows), as a function of descriptors."""
    mu = store.mean(0)
    project = None
    if dims:
        _, s, vt = np.linalg.svd(store - mu, full_matrices=False)
        lam = s ** 2 / len(store)
        k = min(dims, len(store) - 1)
        project = vt[:k].T / (lam[:k] + shrink * lam[:k].mean()) ** power

    def apply(x):
        z = x - mu if project is None else (x - mu) @ project
        return z / np.linalg.norm(z, axis=1, keepdims=True)
    return apply


def recall_at_1(queries, store, truth):
    sims = queries @ store.T
    hits = n = 0
    gap = truth.get('min_frame_gap', 100)
    for q, matches in truth['matches'].items():
        q = int(q)
        s = sims[q].copy()
        if truth['kind'] == 'loop':
            if q < gap:
                continue
            s[q - gap + 1:] = -np.inf
        n += 1
        hits += int(np.argmax(s)) in matches
    return hits / max(n, 1)


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else '../shared/datasets'
    model = sys.argv[2] if len(sys.argv) > 2 else 'models/efficientnet-lite0/efficientnet_lite0.onnx'
    describe = describer(model, 384, 288)

    def folder(path):
        files = sorted(glob.glob(f'{root}/{path}/*.jpg') + glob.glob(f'{root}/{path}/*.png'))
        return np.array([describe(f) for f in files])

    data = {}
    for name in SETS:
        truth = json.load(open(f'{root}/{name}/ground_truth.json'))
        if truth['kind'] == 'pairs':
            queries, store = folder(f'{name}/query'), folder(f'{name}/reference')
        else:
            queries = store = folder(f'{name}/sequence')
        data[name] = (queries, store, truth)

    def others(name):
        condition = name.startswith('town-dev/') and data[name][2]['kind'] == 'pairs'
        return np.concatenate([data[o][1] for o in SETS if o != name and not (
            condition and o.startswith('town-dev/') and data[o][2]['kind'] == 'pairs')])

    print('| fitted on | variant | ' + ' | '.join(n.split('/')[-1] for n in SETS) + ' | mean |')
    print('| --- ' * (len(SETS) + 3) + '|')
    for fitted_on in ('own store', 'other sets'):
        for label, params in VARIANTS:
            if params is None and fitted_on == 'other sets':
                continue
            row = []
            for name in SETS:
                queries, store, truth = data[name]
                if params is not None:
                    w = fit(store if fitted_on == 'own store' else others(name), *params)
                    queries, store = w(queries), w(store)
                row.append(recall_at_1(queries, store, truth))
            cells = ' | '.join(f'{v:.3f}' for v in row)
            print(f'| {fitted_on if params else "-"} | {label} | {cells} | {np.mean(row):.3f} |')


if __name__ == '__main__':
    main()
