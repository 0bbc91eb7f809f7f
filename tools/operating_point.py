"""Chooses the default threshold from `humem eval --json` results of every dev data set.

    tools/operating_point.py [--method Full] [--min-precision 0.98] RESULTS.json...

Each file's clean condition gives, for the method, every query's top-1 answer
(score, valid, has a match). For thresholds on a grid of 0.01, this prints per
data set the recall at the threshold (valid top-1 answers over queries with a
match), the false share of the answers (answered queries whose top-1 is not a
valid match) and the false alarms on queries without a match, then the means over
the data sets, every set weighted alike. The chosen threshold is the lowest one at
which both false-alarm counts are at most 1 - --min-precision (default 0.98, the
closure precision the paper reports, so 2 %) on average over the data sets where
they are defined: the false share of the answers (over the sets that answer at
all, so silence earns nothing) and the share of queries without a match that are
answered (over the sets that have such queries, the loops). A false loop closure
bends a map, a missed one only waits for the next keyframe, so precision comes
first and recall is what is left. Nothing is tuned to one set; the table shows
what each set gives.
"""
import argparse, json

ap = argparse.ArgumentParser()
ap.add_argument("results", nargs="+")
ap.add_argument("--method", default="Full")
ap.add_argument("--min-precision", type=float, default=0.98)
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


def mean_false_share(t):
    """Mean false share of answers over the sets that answer at threshold t (None: none do)."""
    shares = [at(p, t)[1] for p in sets.values() if any(x[0] > t for x in p["tops"])]
    return sum(shares) / len(shares) if shares else None


def mean_alarms(t):
    """Mean share of queries without a match that are answered, over the sets that have some."""
    rates = [at(p, t)[2] for p in sets.values() if at(p, t)[2] is not None]
    return sum(rates) / len(rates) if rates else 0.0


limit = 1 - a.min_precision + 1e-9
grid = [i / 100 for i in range(0, 100)]
chosen = next(
    (t for t in grid if (m := mean_false_share(t)) is not None and m <= limit and mean_alarms(t) <= limit),
    None,
)
names = list(sets)
print(f"method {a.method}; per set: recall at threshold / false share of answers / false alarms on queries without a match")
print("| threshold | " + " | ".join(names) + " | mean recall | mean false share (sets answering) | mean false alarms (loops) |")
print("| --- | " + " | ".join("---" for _ in names) + " | --- | --- | --- |")
for t in grid[::5] + ([chosen] if chosen is not None and chosen not in grid[::5] else []):
    rows = [at(p, t) for p in sets.values()]
    cells = [f"{r:.2f} / {f:.2f} / {'-' if al is None else f'{al:.2f}'}" for r, f, al in rows]
    mark = " **chosen**" if t == chosen else ""
    print(f"| {t:.2f}{mark} | " + " | ".join(cells) + f" | {sum(r[0] for r in rows)/len(rows):.3f} | {'-' if mean_false_share(t) is None else f'{mean_false_share(t):.3f}'} | {mean_alarms(t):.3f} |")
print(f"chosen threshold (lowest with both mean false-alarm counts <= {1 - a.min_precision:.2f}): {chosen}")
