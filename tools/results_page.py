#!/usr/bin/env python3
"""docs/results.md and the README's results table, from the JSON files of
`humem eval` runs (scripts/results.sh makes them): every figure with the
date, the machine, the commit and the command that produced it.

  results_page.py --readme README.md --page docs/results.md RUN.json...

Each RUN.json may have a RUN.command beside it (the command as typed). The
README's table is replaced between its `<!-- results:begin -->` and
`<!-- results:end -->` markers; nothing else in the README is touched.
Standard library only.
"""

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys

# What each development data set is, for the reader.
DESCRIPTIONS = {
    "corridor": ("real", "viewpoint shift"),
    "gardens-daynight": ("real", "day against night"),
    "rtabmap-loop": ("real", "look-alike corridors"),
    "town-dev-loop": ("rendered", "three laps"),
    "town-dev-deep_night": ("rendered", "night"),
    "town-dev-dense_fog": ("rendered", "fog"),
    "town-dev-rain_fog": ("rendered", "rain and fog"),
    "town-dev-sunset_glare": ("rendered", "low sun"),
}
CALIBRATIONS = {"null": "calibrated score (null model)", "raw": "raw score"}
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def machine():
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}"


def commit():
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def load(paths):
    runs = []
    for path in paths:
        with open(path) as f:
            report = json.load(f)
        name = os.path.splitext(os.path.basename(path))[0]
        key = name
        command_file = os.path.splitext(path)[0] + ".command"
        command = open(command_file).read().strip() if os.path.exists(command_file) else ""
        clean = next(c for c in report["conditions"] if c["condition"] == "clean")
        methods = {r["method"]: r for r in clean["results"]}
        # Shown as the data set's folder (town-dev/loop), from the command.
        shown = command.rsplit("$DATASETS/", 1)[-1] if "$DATASETS/" in command else name
        runs.append({"name": shown, "key": key, "report": report, "command": command, "methods": methods})
    return runs


def answered(r):
    p = r["precision"]
    return p["answered"], p["queries"], p["false_top"]


def page(runs, when, where, head):
    first = runs[0]["report"]
    lines = [
        "# Results",
        "",
        "Every figure on this page comes from one run of `scripts/results.sh`:",
        "`humem eval` with the shipped defaults on each development data set,",
        "method Full (the full HuMem-VPR score) against the ORB bag-of-words",
        "baseline (like ORB-SLAM3's DBoW2), at most 100 evenly spaced queries of",
        "each kind (with and without a true place). The README's table is made",
        "from the same runs. Run it again to measure your own machine or build;",
        "the data sets are described in [Evaluation](evaluation.md).",
        "",
        "| | |",
        "| --- | --- |",
        f"| measured | {when} |",
        f"| machine | {where} |",
        f"| commit | `{head}` |",
        f"| operating point | {CALIBRATIONS.get(first['calibration'], first['calibration'])}, threshold {first['threshold']:.2f}, "
        f"at most {first['max_candidates']} candidates (the defaults) |",
        f"| objects | {first['objects']} |",
        "",
        "\"answered\" counts the queries whose best candidate passed the threshold;",
        "\"wrong\" those of them whose first candidate is not a true place; \"false",
        "alarms\" the answered queries that have no true place at all. ORB-BoW has",
        "no calibrated score and answers every query. Latency is the median of the",
        "timed queries on the machine above, the models included for HuMem.",
        "`$DATASETS` is the folder of development data sets.",
        "",
        "| data set | images | method | R@1 | R@5 | MRR | answered | wrong | false alarms | candidate precision | median ms | command |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for run in runs:
        kind, what = DESCRIPTIONS.get(run["key"], ("", ""))
        for method, r in run["methods"].items():
            p = r["precision"]
            without = p["queries"] - p["with_match"]
            alarms = f"{p['false_no_match']}/{without}" if without else "-"
            lines.append(
                f"| {run['name']} | {kind}, {what} | {method} | {r['recall_at_1']:.3f} | {r['recall_at_5']:.3f} "
                f"| {r['mrr']:.3f} | {p['answered']}/{p['queries']} | {p['false_top']} | {alarms} "
                f"| {p['candidate_precision']:.3f} | {r['latency']['median_ms']:.1f} | `{run['command']}` |")
    lines += ["", "## Means by kind of image", "",
              "Real images and renders apart: a default that wins on renders can lose on real images.", "",
              "| images | data sets | method | mean R@1 | mean R@5 | answered | wrong |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for kind in ("real", "rendered"):
        group = [r for r in runs if DESCRIPTIONS.get(r["key"], ("",))[0] == kind]
        if not group:
            continue
        for method in group[0]["methods"]:
            rs = [g["methods"][method] for g in group if method in g["methods"]]
            mean1 = sum(r["recall_at_1"] for r in rs) / len(rs)
            mean5 = sum(r["recall_at_5"] for r in rs) / len(rs)
            a = sum(answered(r)[0] for r in rs)
            q = sum(answered(r)[1] for r in rs)
            w = sum(answered(r)[2] for r in rs)
            lines.append(f"| {kind} | {len(rs)} | {method} | {mean1:.3f} | {mean5:.3f} | {a}/{q} | {w} |")
    return "\n".join(lines) + "\n"


def readme_table(runs, when, where, head):
    lines = [
        BEGIN,
        f"Measured {when} on {where}, commit `{head}`; the commands, every",
        "figure and the means for real and rendered images are on",
        "[Results](docs/results.md) (`scripts/results.sh` writes both).",
        "",
        "| data set | images | HuMem R@1 | ORB-BoW R@1 | HuMem answered (wrong) | ORB-BoW answered (wrong) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    totals = [0, 0, 0, 0, 0, 0]
    for run in runs:
        kind, what = DESCRIPTIONS.get(run["key"], ("", ""))
        full, orb = run["methods"].get("Full"), run["methods"].get("ORB-BoW")
        if not full or not orb:
            continue
        fa, fq, fw = answered(full)
        oa, oq, ow = answered(orb)
        totals = [t + v for t, v in zip(totals, (fa, fq, fw, oa, oq, ow))]
        lines.append(f"| {run['name']} | {kind}, {what} | {full['recall_at_1']:.3f} | {orb['recall_at_1']:.3f} "
                     f"| {fa}/{fq} ({fw}) | {oa}/{oq} ({ow}) |")
    lines.append(f"| **all {len(runs)}** | | | | **{totals[0]}/{totals[1]} ({totals[2]})** "
                 f"| **{totals[3]}/{totals[4]} ({totals[5]})** |")
    lines.append(END)
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--readme", required=True)
    parser.add_argument("--page", required=True)
    parser.add_argument("--commit", help="the commit the binary was built from (default: HEAD now)")
    parser.add_argument("runs", nargs="+")
    args = parser.parse_args()
    runs = load(args.runs)
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    where, head = machine(), args.commit or commit()
    with open(args.page, "w") as f:
        f.write(page(runs, when, where, head))
    text = open(args.readme).read()
    if BEGIN not in text or END not in text:
        sys.exit(f"{args.readme} has no {BEGIN} ... {END} markers")
    before, rest = text.split(BEGIN, 1)
    _, after = rest.split(END, 1)
    with open(args.readme, "w") as f:
        f.write(before + readme_table(runs, when, where, head) + after)


if __name__ == "__main__":
    main()
