"""Chooses the default threshold from `humem eval --json` results of every dev data set.

    tools/operating_point.py [--method Full] [--max-false 0.05] RESULTS.json...

Each file's clean condition gives, for the method, every query's top-1 answer
(score, valid, has a match). For thresholds on a grid of 0.01, this prints per
data set the recall at the threshold (valid top-1 answers over queries with a
match), the false share of the answers (answered queries whose top-1 is not a
valid match) and the false alarms on queries without a match, then the mean over
the data sets, every set weighted alike. The chosen threshold is the lowest one
at which the mean false share of answers is at most --max-false: the most recall
the sets allow at that precision on average. Nothing is tuned to one set.
"""
import argparse, json

ap = argparse.ArgumentParser()
ap.add_argument("results", nargs="+")
ap.add_argument("--method", default="Full")
ap.add_argument("--max-false", type=float, default=0.05)
a = ap.parse_args()

sets = {}
for path in a.results:
    r = json.load(open(path))
    clean = r["conditions"][0]
    m = next((x for x in clean["results"] if x["method"] == a.method), None)
    if m is None:
        raise SystemExit(f"{path}: no method {a.method!r}")
    sets[r["dataset"] + (" (annotations)" if r.get("objects") == "annotations" else "")] = m["precision"]


def at(p, t):
    tops = p["tops"]
    with_match = p["with_match"]
    without = p["queries"] - with_match
    answered = [x for x in tops if x[0] > t]
    recall = sum(1 for s, v, h in answered if v) / with_match if with_match else 0.0
    false_share = sum(1 for s, v, h in answered if not v) / len(answered) if answered else 0.0
    alarms = sum(1 for s, v, h in answered if not h) / without if without else None
    return recall, false_share, alarms


grid = [i / 100 for i in range(0, 100)]
chosen = None
for t in grid:
    rows = [at(p, t) for p in sets.values()]
    mean_false = sum(r[1] for r in rows) / len(rows)
    if chosen is None and mean_false <= a.max_false:
        chosen = t
names = list(sets)
print(f"method {a.method}; per set: recall at threshold / false share of answers / false alarms on queries without a match")
print("| threshold | " + " | ".join(names) + " | mean recall | mean false share |")
print("| --- | " + " | ".join("---" for _ in names) + " | --- | --- |")
for t in grid[::5] + ([chosen] if chosen is not None and chosen not in grid[::5] else []):
    rows = [at(p, t) for p in sets.values()]
    cells = [f"{r:.2f} / {f:.2f} / {'-' if al is None else f'{al:.2f}'}" for r, f, al in rows]
    mark = " **chosen**" if t == chosen else ""
    print(f"| {t:.2f}{mark} | " + " | ".join(cells) + f" | {sum(r[0] for r in rows)/len(rows):.3f} | {sum(r[1] for r in rows)/len(rows):.3f} |")
print(f"chosen threshold (lowest with mean false share <= {a.max_false}): {chosen}")
