#!/usr/bin/env python3
"""One Markdown table from the JSON files of several `humem eval` runs.

Used by scripts/eval-all.sh to make the README's results section; standard
library only, so it runs with any Python 3.
"""

import json
import sys


def rows(report):
    name = report["dataset"]
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


def main(paths):
    print("| data set | condition | method | R@1 | R@5 | MRR | mean ms | median ms | p95 ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for path in paths:
        with open(path) as f:
            report = json.load(f)
        for row in rows(report):
            print(row)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: eval_table.py RUN.json...")
    main(sys.argv[1:])
