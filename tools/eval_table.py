#!/usr/bin/env python3
"""One Markdown table from the JSON files of several `humem eval` runs
(optionally only some methods: --methods SCAL,Full,ORB-BoW): recall, the
precision figures at the operating point, and the median latency.

Used by scripts/eval-all.sh to make the results section of docs/evaluation.md; standard
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
            p = r["precision"]
            without = p["queries"] - p["with_match"]
            alarms = f"{p['false_no_match']}/{without}" if without else "-"
            yield (
                f"| {name} | {condition['condition']} | {r['method']} "
                f"| {r['recall_at_1']:.3f} | {r['recall_at_5']:.3f} | {r['mrr']:.3f} "
                f"| {p['answered']}/{p['queries']} | {p['false_top']} | {alarms} "
                f"| {p['candidate_precision']:.3f} | {p['recall_at_full_precision']:.3f} "
                f"| {lat['median_ms']:.1f} |"
            )


def main(paths, methods=None):
    print("| data set | condition | method | R@1 | R@5 | MRR | answered | false top-1 | false alarms (no match) | candidate precision | R@100%P | median ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
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
