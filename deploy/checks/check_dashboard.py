#!/usr/bin/env python3
"""Static checks of the Grafana dashboard JSON.

  check_dashboard.py deploy/grafana/dashboards/humem.json

Unique panel ids, non-overlapping layout, a datasource variable, robot and map
(and instance) query variables, every panel with at least one non-empty
PromQL expression, and every datasource reference (panels, targets,
variables) going through the datasource variable. Whether the expressions
select real series is check_live.py's job.
"""

import json
import sys

from common import Report, dashboard_panels, uses_datasource_variable


def main(path: str) -> None:
    report = Report(f"dashboard {path}")
    with open(path, encoding="utf-8") as f:
        dashboard = json.load(f)
    for key in ("uid", "title", "schemaVersion"):
        report.check(bool(dashboard.get(key)), f"has {key}")

    variables = {v.get("name"): v for v in dashboard.get("templating", {}).get("list", [])}
    ds = [v for v in variables.values() if v.get("type") == "datasource"]
    report.check(
        len(ds) == 1 and ds[0].get("name") == "datasource" and ds[0].get("query") == "prometheus",
        "one datasource variable `datasource` of type prometheus",
    )
    for name in ("instance", "robot", "map"):
        v = variables.get(name)
        if not report.check(v is not None and v.get("type") == "query", f"query variable `{name}`"):
            continue
        query = v.get("query")
        query = query.get("query") if isinstance(query, dict) else query
        report.check(
            isinstance(query, str) and query.startswith("label_values(") and query.rstrip(")").endswith(name),
            f"`{name}` is label_values(..., {name}): {query}",
        )
        report.check(uses_datasource_variable(v.get("datasource")), f"`{name}` queries through $datasource")
        report.check(v.get("includeAll") is True and v.get("allValue") == ".*", f"`{name}` has All (.*)")

    panels = dashboard_panels(dashboard)
    ids = [p.get("id") for p in panels]
    duplicates = sorted({i for i in ids if ids.count(i) > 1}, key=str)
    report.check(all(isinstance(i, int) for i in ids) and not duplicates,
                 f"{len(ids)} panel ids, unique (duplicates: {duplicates or 'none'})")

    cells = {}
    overlaps = []
    for p in panels:
        g = p.get("gridPos") or {}
        if not all(isinstance(g.get(k), int) for k in ("x", "y", "w", "h")) or g["x"] + g["w"] > 24:
            report.fail(f"panel {p.get('id')} {p.get('title')!r}: bad gridPos {g}")
            continue
        for x in range(g["x"], g["x"] + g["w"]):
            for y in range(g["y"], g["y"] + g["h"]):
                if (x, y) in cells:
                    overlaps.append((cells[(x, y)], p.get("id")))
                cells[(x, y)] = p.get("id")
    report.check(not overlaps, f"panels do not overlap {sorted(set(overlaps))[:5] if overlaps else ''}")

    expressions = 0
    for p in panels:
        label = f"panel {p.get('id')} {p.get('title')!r}"
        if p.get("type") == "row":
            if p.get("targets"):
                report.fail(f"{label}: a row has no queries")
            continue
        targets = p.get("targets") or []
        exprs = [t.get("expr", "") for t in targets]
        if not targets or not all(isinstance(e, str) and e.strip() for e in exprs):
            report.fail(f"{label}: every panel needs queries with a non-empty expr")
            continue
        expressions += len(exprs)
        refs = [p.get("datasource")] + [t.get("datasource") for t in targets]
        if not all(uses_datasource_variable(r) for r in refs):
            report.fail(f"{label}: datasource must be {{\"uid\": \"${{datasource}}\"}}, got {refs}")
        ref_ids = [t.get("refId") for t in targets]
        if len(set(ref_ids)) != len(ref_ids):
            report.fail(f"{label}: duplicate refIds {ref_ids}")
    report.ok(f"{expressions} expressions in {sum(p.get('type') != 'row' for p in panels)} panels, all through $datasource")

    all_exprs = " ".join(t.get("expr", "") for p in panels for t in p.get("targets") or [])
    for name in ("robot", "map", "instance"):
        report.check(f"${name}" in all_exprs, f"some panel filters by ${name}")
    report.finish()


if __name__ == "__main__":
    main(sys.argv[1])
