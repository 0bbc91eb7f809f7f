#!/usr/bin/env python3
"""One Markdown table from the JSON files of several `humem eval` runs
(optionally only some methods: --methods SCAL,Full,ORB-BoW).

Used by scripts/eval-all.sh to make the README's results section; standard
library only, so it runs with any Python 3.
"""

import json
import os
import sys


def rows(report, name):
    name = name.removesuffix("-annotated")
    if report.get("objects") == "annotations":
        name += " (ground-truth objects)"
    for condition in report["conditions"]:
        for r in condition["results"]:
            lat = r["latency"]
            yield (
                f"| {name} | {condition['condition']} | {r['method']} "
                f"| {r['recall_at_1']:.3f} | {r['recall_at_5']:.3f} | {r['mrr']:.3f} "
                f"| {lat['mean_ms']:.1f} | {lat['median_ms']:.1f} | {lat['p95_ms']:.1f} |"
            )


def main(paths, methods=None):
    print("| data set | condition | method | R@1 | R@5 | MRR | mean ms | median ms | p95 ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for path in paths:
        with open(path) as f:
            report = json.load(f)
        # The run's name (the JSON file's), e.g. town-dev-dense_fog.
        name = os.path.basename(path).removesuffix(".json")
        for row in rows(report, name):
            if methods is None or row.split(" | ")[2] in methods:
                print(row)


if __name__ == "__main__":
    args = sys.argv[1:]
    methods = None
    if args[:1] == ["--methods"]:
        methods = set(args[1].split(","))
        args = args[2:]
    if not args:
        sys.exit("usage: eval_table.py [--methods SCAL,Full,...] RUN.json...")
    main(args, methods)
