#!/usr/bin/env python3
"""faiss on the vectors `humem bench graph --export DIR` wrote, for a
side-by-side table with HuMem's neighbour graph on the same machine.

Reads DIR/base.f32, DIR/queries.f32 and DIR/truth.u32 (the exact
inner-product top-5 of each query), builds faiss HNSW (IndexHNSWFlat, inner
product, M and efConstruction as HuMem's graph: 16 and 128) and IVF
(IndexIVFFlat over sqrt(N)·4 lists), and prints per search setting the
median latency of one query on one thread and the recall of the exact
top-1 (the first result is the exact best row), with build time and memory
per keyframe. Needs `pip install faiss-cpu numpy`.

    python3 tools/faiss_side_by_side.py DIR --dim 1280
"""

import argparse
import time
from pathlib import Path

import faiss
import numpy as np


def median_ms(index, queries, k):
    times, found = [], []
    for q in queries:
        started = time.perf_counter()
        _, ids = index.search(q[None, :], k)
        times.append((time.perf_counter() - started) * 1e3)
        found.append(ids[0])
    return float(np.median(times)), found


def recall_top1(found, truth):
    return float(np.mean([len(f) > 0 and f[0] == t[0] for f, t in zip(found, truth)]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dir", type=Path)
    parser.add_argument("--dim", type=int, required=True)
    parser.add_argument("--build-threads", type=int, default=2)
    args = parser.parse_args()
    base = np.fromfile(args.dir / "base.f32", dtype=np.float32).reshape(-1, args.dim)
    queries = np.fromfile(args.dir / "queries.f32", dtype=np.float32).reshape(-1, args.dim)
    truth = np.fromfile(args.dir / "truth.u32", dtype=np.uint32).reshape(-1, 5)
    n = len(base)
    print(f"faiss {faiss.__version__}: {n} x {args.dim}, {len(queries)} queries, one search thread")
    print("| index | setting | build s | bytes/keyframe | search ms | top-1 recall |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")

    faiss.omp_set_num_threads(1)
    flat = faiss.IndexFlatIP(args.dim)
    flat.add(base)
    ms, found = median_ms(flat, queries, 1)
    print(f"| Flat IP | exact | 0 | {4 * args.dim} | {ms:.3f} | {recall_top1(found, truth):.3f} |")
    del flat

    faiss.omp_set_num_threads(args.build_threads)
    hnsw = faiss.IndexHNSWFlat(args.dim, 16, faiss.METRIC_INNER_PRODUCT)
    hnsw.hnsw.efConstruction = 128
    started = time.perf_counter()
    hnsw.add(base)
    build = time.perf_counter() - started
    faiss.omp_set_num_threads(1)
    size = len(faiss.serialize_index(hnsw)) / n
    for ef in (16, 32, 64, 128, 256, 512):
        hnsw.hnsw.efSearch = ef
        ms, found = median_ms(hnsw, queries, 1)
        print(f"| HNSW M=16 | efSearch={ef} | {build:.1f} | {size:.0f} | {ms:.3f} | {recall_top1(found, truth):.3f} |")
    del hnsw

    lists = int(4 * np.sqrt(n))
    faiss.omp_set_num_threads(args.build_threads)
    quantizer = faiss.IndexFlatIP(args.dim)
    ivf = faiss.IndexIVFFlat(quantizer, args.dim, lists, faiss.METRIC_INNER_PRODUCT)
    started = time.perf_counter()
    ivf.train(base[np.random.default_rng(0).choice(n, min(n, 40 * lists), replace=False)])
    ivf.add(base)
    build = time.perf_counter() - started
    faiss.omp_set_num_threads(1)
    size = len(faiss.serialize_index(ivf)) / n
    for probes in (1, 2, 4, 8, 16, 32, 64):
        ivf.nprobe = probes
        ms, found = median_ms(ivf, queries, 1)
        print(f"| IVF{lists},Flat | nprobe={probes} | {build:.1f} | {size:.0f} | {ms:.3f} | {recall_top1(found, truth):.3f} |")


if __name__ == "__main__":
    main()
