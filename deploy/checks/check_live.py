#!/usr/bin/env python3
"""Evaluates the dashboard's and the alerting rules' PromQL against a live
Prometheus that scrapes a live HuMem, and fails on any that selects nothing.

  check_live.py --prometheus http://127.0.0.1:PORT --dashboard deploy/grafana/dashboards/humem.json

- Waits until Prometheus has scraped the target and evaluated every rule group,
  and fails on any rule whose evaluation errors.
- Resolves the dashboard's query variables (label_values) the way Grafana
  does, through the series API, and picks the first value of each (robot,
  map, instance), so the panels are evaluated for one concrete robot and map.
- Evaluates every panel query with $__rate_interval = --rate-interval.
- Evaluates every alerting rule's operands: the expression is split at its
  top-level comparisons and set operators (`a / b > 0.01` -> `a / b`), and
  each operand that is not a constant must return series. `absent(x)` is
  checked as `x`. So a rule whose condition is normally false still proves
  that the series it watches exist.
- Checks the stage -> part mapping of the "paper's breakdown" panel against
  the stage names in the metric's HELP text.

Prints a table (source, series, finite values, expression) and exits 1 if
any expression returned no series or only NaN.
"""

import argparse
import json
import math
import re
import sys
import time
import urllib.parse
import urllib.request

from common import dashboard_panels

COMPARISON = re.compile(r"==|!=|>=|<=|>|<|\b(?:and|or|unless)\b")
MODIFIERS = re.compile(
    r"^\s*(?:bool\s+)?(?:(?:on|ignoring)\s*\([^)]*\)\s*)?(?:(?:group_left|group_right)\s*(?:\([^)]*\))?\s*)?"
)
ABSENT = re.compile(r"^absent(?:_over_time)?\s*\((.*)\)$", re.S)
LABEL_VALUES = re.compile(r"^label_values\(\s*(?:(.*),\s*)?(\w+)\s*\)$", re.S)
BREAKDOWN = re.compile(r'"part",\s*"([^"]+)",\s*"stage",\s*"([^"]+)"')


class Prometheus:
    def __init__(self, url: str):
        self.url = url.rstrip("/")

    def get(self, path: str, **params) -> dict:
        query = urllib.parse.urlencode(params, doseq=True)
        with urllib.request.urlopen(f"{self.url}{path}?{query}", timeout=20) as response:
            body = json.load(response)
        if body.get("status") != "success":
            raise RuntimeError(f"{path} {params}: {body}")
        return body["data"]

    def query(self, expr: str) -> tuple[str, list]:
        data = self.get("/api/v1/query", query=expr)
        return data["resultType"], data["result"]


def split_operands(expr: str) -> list[str]:
    """The operands of the top-level comparison and set operators of `expr`."""
    operands, depth, start, quote, i = [], 0, 0, None, 0
    while i < len(expr):
        c = expr[i]
        if quote:
            if c == "\\":
                i += 2
                continue
            if c == quote:
                quote = None
        elif c in "\"'`":
            quote = c
        elif c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        elif depth == 0:
            m = COMPARISON.match(expr, i)
            if m:
                operands.append(expr[start:i])
                i = start = m.end()
                continue
        i += 1
    operands.append(expr[start:])
    return [MODIFIERS.sub("", o, count=1).strip() for o in operands if o.strip()]


def substitute(expr: str, values: dict[str, str]) -> str:
    """Grafana's variable syntaxes: $name, ${name}, ${name:fmt}, [[name]]."""
    def value(m):
        name = next(g for g in m.groups() if g)
        return values.get(name, m.group(0))
    return re.sub(r"\$\{(\w+)(?::\w+)?\}|\[\[(\w+)\]\]|\$(\w+)", value, expr)


def regex_escape(value: str) -> str:
    """A label value as a PromQL regex inside a double-quoted string."""
    return re.sub(r"([.+*?()\[\]{}|^$\\])", r"\\\\\1", value)


def one_line(expr: str) -> str:
    return re.sub(r"\s+", " ", expr).strip()


def summarise(result_type: str, result: list) -> tuple[int, int]:
    """(series, series with a finite value)."""
    if result_type == "scalar":
        return 1, int(math.isfinite(float(result[1])))
    finite = 0
    for series in result:
        values = series.get("values") or [series.get("value")]
        finite += any(v and math.isfinite(float(v[1])) for v in values)
    return len(result), finite


def wait_until_ready(prom: Prometheus, timeout: float, failures: list[str]) -> list[dict]:
    """Waits for a successful scrape and one evaluation of every rule; returns the rules."""
    deadline = time.time() + timeout
    while True:
        targets = prom.get("/api/v1/targets")["activeTargets"]
        groups = prom.get("/api/v1/rules")["groups"]
        rules = [r for g in groups for r in g["rules"]]
        scraped = targets and all(t["health"] == "up" for t in targets)
        evaluated = rules and all(r.get("lastEvaluation", "").startswith("2") and
                                  not r["lastEvaluation"].startswith("0001") for r in rules)
        if scraped and evaluated:
            break
        if time.time() > deadline:
            failures.append(f"not ready after {timeout:.0f} s: targets {[(t['scrapeUrl'], t['health'], t.get('lastError')) for t in targets]}, "
                            f"{len(rules)} rules")
            break
        time.sleep(0.5)
    for r in rules:
        if r.get("health") != "ok":
            failures.append(f"rule {r.get('name')}: health {r.get('health')}: {r.get('lastError')}")
    return rules


def resolve_variables(prom: Prometheus, dashboard: dict, failures: list[str]) -> dict[str, str]:
    values: dict[str, str] = {}
    for v in dashboard.get("templating", {}).get("list", []):
        if v.get("type") != "query":
            continue
        query = v.get("query")
        query = query.get("query") if isinstance(query, dict) else query
        m = LABEL_VALUES.match(query or "")
        if not m:
            failures.append(f"variable {v['name']}: cannot evaluate {query!r} (only label_values)")
            continue
        selector, label = m.group(1), m.group(2)
        if selector:
            series = prom.get("/api/v1/series", **{"match[]": substitute(selector, values),
                                                  "start": time.time() - 600, "end": time.time()})
            found = sorted({s[label] for s in series if label in s})
        else:
            found = sorted(prom.get(f"/api/v1/label/{label}/values"))
        print(f"  variable {v['name']:<9} {query}  ->  {found[:6]}{' ...' if len(found) > 6 else ''}")
        if not found:
            failures.append(f"variable {v['name']}: {query} has no values")
            continue
        values[v["name"]] = regex_escape(found[0])
    return values


def check_breakdown(prom: Prometheus, expr: str, result: list, failures: list[str]) -> None:
    """Every stage the service documents maps to one of the paper's parts,
    and every series of the panel has a part."""
    mapping = BREAKDOWN.findall(expr)
    meta = prom.get("/api/v1/metadata", metric="humem_stage_duration_seconds").get("humem_stage_duration_seconds", [])
    help_text = meta[0]["help"] if meta else ""
    stages = [s.strip() for s in help_text.split(":", 1)[-1].split(",") if s.strip()] if ":" in help_text else []
    if not stages:
        failures.append(f"breakdown: no stage list in the HELP of humem_stage_duration_seconds: {help_text!r}")
    for stage in stages:
        parts = [p for p, regex in mapping if re.fullmatch(regex, stage)]
        if len(parts) != 1:
            failures.append(f"breakdown: stage {stage!r} maps to {parts or 'no part'}")
    unmapped = [s["metric"] for s in result if "part" not in s["metric"]]
    if unmapped:
        failures.append(f"breakdown: series without a part (a stage the mapping misses): {unmapped}")
    print(f"  breakdown: stages {stages} -> parts {sorted({p for p, _ in mapping})}; "
          f"now reporting {sorted(s['metric'].get('part', '?') for s in result)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--prometheus", required=True)
    parser.add_argument("--dashboard", required=True)
    parser.add_argument("--rate-interval", default="1m")
    parser.add_argument("--timeout", type=float, default=30)
    args = parser.parse_args()
    prom = Prometheus(args.prometheus)
    failures: list[str] = []

    rules = wait_until_ready(prom, args.timeout, failures)
    with open(args.dashboard, encoding="utf-8") as f:
        dashboard = json.load(f)
    values = resolve_variables(prom, dashboard, failures)
    values.update({"__rate_interval": args.rate_interval, "__interval": "15s", "__range": args.rate_interval})

    rows = []  # (kind, source, expression)
    for panel in dashboard_panels(dashboard):
        for target in panel.get("targets") or []:
            rows.append(("panel", f"{panel.get('title')} [{target.get('refId')}]", substitute(target["expr"], values)))
    alerting = [r for r in rules if r.get("type") == "alerting"]
    for rule in alerting:
        operands = split_operands(rule["query"])
        for i, operand in enumerate(operands, 1):
            m = ABSENT.match(operand)
            rows.append(("rule", f"{rule['name']} [{i}/{len(operands)}]{' (absent arg)' if m else ''}",
                         m.group(1) if m else operand))

    empty, thresholds = [], 0
    print(f"  {'kind':<5} {'source':<58} {'series':>6} {'finite':>6}  expression")
    for kind, source, expr in rows:
        try:
            result_type, result = prom.query(expr)
        except Exception as e:  # a PromQL error is a failure too
            failures.append(f"{kind} {source}: {e}")
            continue
        if kind == "rule" and result_type == "scalar":
            thresholds += 1  # a constant: the threshold
            continue
        series, finite = summarise(result_type, result)
        flag = "" if finite else "   <-- EMPTY" if not series else "   <-- NaN only"
        text = one_line(expr)
        print(f"  {kind:<5} {source[:58]:<58} {series:>6} {finite:>6}  {text[:150]}{'...' if len(text) > 150 else ''}{flag}")
        if not finite:
            empty.append(f"{kind} {source}: {one_line(expr)}")
        if '"part"' in expr:
            check_breakdown(prom, expr, result, failures)

    print(f"  {len(rows) - thresholds} expressions evaluated: {sum(k == 'panel' for k, _, _ in rows)} from the dashboard, "
          f"{sum(k == 'rule' for k, _, _ in rows) - thresholds} operands of {len(alerting)} alerting rules "
          f"({thresholds} constant thresholds left out)")
    for e in empty:
        failures.append(f"no data: {e}")
    if failures:
        print("live check FAILED:")
        for f in failures:
            print(f"  - {f}")
        sys.exit(1)
    print("live check: every dashboard query and alert operand returns data")


if __name__ == "__main__":
    main()
