#!/usr/bin/env python3
"""Evaluates the HuMem ORB-SLAM3 harness runs (run.sh) against a data set's poses.

For every run folder (RUNS/<mode>-<n>, written by humem_orbslam3_mono and
run.sh) it reads keyframes.txt, maps.txt, counters.txt, events.txt (the
patch's "[ORB-SLAM3 event]" lines) and, for HuMem runs, store.jsonl (`humem
export`), and prints one Markdown table:

  keyframes, loop queries, candidates sent to geometric verification (true),
  their precision per lap, ORB-SLAM3's verdicts on candidates (the patch's
  "verdict" event lines: accepted, and how many the plugin reported to
  HuMem), accepted loops and merges (true), relocalisations, maps at the
  end, keyframe ATE (Sim3-aligned RMSE) and whether HuMem's store holds the
  map ids and poses ORB-SLAM3 holds.

Laps: the data sets carry no lap index, so the frames are split into
--laps (3) equal parts by image index (town-dev/loop drives its loop three
times); a candidate counts in the lap of its query keyframe's frame.

"True" uses the data set's ground-truth poses of the two keyframes' source
frames: <= 5 m apart and <= 30 degrees between the camera orientations. A
candidate 5-10 m away within 30 degrees is a near miss: the same street seen
from a little farther on, which geometry may still match; near misses are
counted apart and left out of the precision.

Modes: `humem` and every `humem-...` mode (run.sh --mode-env) are HuMem runs;
`dbow2` is ORB-SLAM3's own. Several --runs-dir folders (batches run at
different times) make one table; a run's name then carries its batch.

  evaluate.py --dataset town-dev/loop --runs-dir RUNS [RUNS2 ...] [--laps 3] [--json out.json]
"""
import argparse
import json
import math
import os
import re
import sys

import numpy as np

MAX_DIST_M = 5.0
MAX_ANGLE_DEG = 30.0
# Beyond the truth's radius but within this, (and within MAX_ANGLE_DEG): a near miss.
NEAR_MISS_M = 10.0
# Store check tolerances (ORB-SLAM3 map units; monocular maps have an
# arbitrary scale of about the scene depth).
STORE_TOL_T = 1e-3
STORE_TOL_DEG = 0.05


def quat_to_rot(qx, qy, qz, qw):
    q = np.array([qw, qx, qy, qz], dtype=float)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rot_angle_deg(Ra, Rb):
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def load_gt(dataset):
    """Ground truth: list of (timestamp, position, rotation) by image index."""
    gt = []
    with open(os.path.join(dataset, "sequence_poses.txt")) as f:
        for line in f:
            if not line.strip() or line.startswith("#"):
                continue
            v = [float(x) for x in line.split()]
            gt.append((v[0], np.array(v[1:4]), quat_to_rot(*v[4:8])))
    return gt


class Frames:
    """Maps timestamps (as printed by the patch, 6 decimals) to image indices."""

    def __init__(self, gt):
        self.ts = np.array([g[0] for g in gt])

    def index(self, t):
        i = int(np.argmin(np.abs(self.ts - t)))
        if abs(self.ts[i] - t) > 1e-3:
            raise ValueError("timestamp %f matches no frame" % t)
        return i


def true_pair(gt, i, j):
    d = float(np.linalg.norm(gt[i][1] - gt[j][1]))
    a = rot_angle_deg(gt[i][2], gt[j][2])
    return d <= MAX_DIST_M and a <= MAX_ANGLE_DEG, d, a


def near_miss(gt, i, j):
    """Not a true place, but 5-10 m away within 30 degrees."""
    ok, d, a = true_pair(gt, i, j)
    return not ok and d <= NEAR_MISS_M and a <= MAX_ANGLE_DEG


def is_humem(mode):
    return mode == "humem" or mode.startswith("humem-")


def precision(true, all_, near):
    """true / (all - near misses), as text."""
    judged = all_ - near
    return "%.0f %%" % (100.0 * true / judged) if judged else "—"


def umeyama_rmse(src, dst):
    """Sim3 (rotation, translation, scale) aligning src to dst (Umeyama 1991); returns RMSE."""
    n = src.shape[0]
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs ** 2).sum() / n
    s = np.trace(np.diag(D) @ S) / var_s if var_s > 0 else 1.0
    t = mu_d - s * R @ mu_s
    err = dst - (s * (R @ src.T).T + t)
    return float(np.sqrt((err ** 2).sum(1).mean()))


def read_kv(path):
    out = {}
    if os.path.exists(path):
        with open(path) as f:
            for line in f:
                p = line.split(None, 1)
                if len(p) == 2:
                    out[p[0]] = p[1].strip()
    return out


def read_keyframes(path):
    kfs = []
    with open(path) as f:
        for line in f:
            if not line.strip() or line.startswith("#"):
                continue
            v = line.split()
            kfs.append({
                "index": int(v[0]), "kf": int(v[1]), "frame": int(v[2]), "map": int(v[3]), "t": float(v[4]),
                "p": np.array([float(x) for x in v[5:8]]), "R": quat_to_rot(*[float(x) for x in v[8:12]]),
            })
    return kfs


KF_RE = r"KF (\d+) frame (\d+) t ([-0-9.e+]+)"
CAND_RE = re.compile(r"^candidates " + KF_RE + r" loop (\d+) \[([^\]]*)\] merge (\d+) \[([^\]]*)\]")
PAIR_RE = re.compile(r"^(loop|merge) " + KF_RE + r" matched " + KF_RE)
RELOC_RE = re.compile(r"^relocalised frame (\d+) t ([-0-9.e+]+)")
ATTEMPT_RE = re.compile(r"^relocalisation attempt frame (\d+) t ([-0-9.e+]+) candidates (\d+)")
# ORB-SLAM3's verdict on one candidate (the patch: after Sim3 / the coincidence check, a loop
# correction or merge, or a relocalisation attempt).
VERDICT_RE = re.compile(r"^verdict (loop|merge) (accepted|rejected) " + KF_RE + r" candidate " + KF_RE)
RELOC_VERDICT_RE = re.compile(r"^verdict relocalisation (accepted|rejected) frame (\d+) t ([-0-9.e+]+) candidate "
                              + KF_RE)


def store_check(store_path, kfs):
    """Compares `humem export` with ORB-SLAM3's live keyframes: ids, map ids, poses."""
    if not os.path.exists(store_path):
        return None, "no export"
    store = {}
    with open(store_path) as f:
        for line in f:
            line = line.strip()
            if not line.startswith("{"):
                continue
            o = json.loads(line)
            if o.get("robotId", "orbslam3") != "orbslam3":
                continue
            pose = o.get("pose", {})
            tr, ro = pose.get("translation", {}), pose.get("rotation", {})
            store[int(o.get("keyframeId", 0))] = {
                "map": int(o.get("mapId", 0)),
                "p": np.array([float(tr.get(k, 0.0)) for k in ("x", "y", "z")]),
                "R": quat_to_rot(float(ro.get("x", 0.0)), float(ro.get("y", 0.0)), float(ro.get("z", 0.0)),
                                 float(ro.get("w", 1.0))),
            }
    missing = bad_map = bad_pose = 0
    worst_t = worst_a = 0.0
    live = set()
    for k in kfs:
        live.add(k["kf"])
        s = store.get(k["kf"])
        if s is None:
            missing += 1
            continue
        if s["map"] != k["map"]:
            bad_map += 1
        dt = float(np.linalg.norm(s["p"] - k["p"]))
        da = rot_angle_deg(s["R"], k["R"])
        worst_t, worst_a = max(worst_t, dt), max(worst_a, da)
        if dt > STORE_TOL_T or da > STORE_TOL_DEG:
            bad_pose += 1
    extra = len([i for i in store if i not in live])
    ok = missing == 0 and bad_map == 0 and bad_pose == 0 and extra == 0
    detail = {"store": len(store), "missing": missing, "map_mismatch": bad_map, "pose_mismatch": bad_pose,
              "extra": extra, "worst_dt": worst_t, "worst_deg": worst_a}
    if ok:
        text = "match (%d)" % len(kfs)
    else:
        parts = []
        for key, label in (("map_mismatch", "map ids"), ("pose_mismatch", "poses"), ("missing", "missing"),
                           ("extra", "extra")):
            if detail[key]:
                parts.append("%d %s" % (detail[key], label))
        text = "MISMATCH: " + ", ".join(parts)
    return ok, text, detail


def evaluate_run(rd, gt, frames, laps=3):
    run = read_kv(os.path.join(rd, "run.txt"))
    counters = read_kv(os.path.join(rd, "counters.txt"))
    res = {"dir": os.path.basename(rd), "mode": run.get("mode", "?"), "run": run.get("run", "?"),
           "driver_rc": run.get("driver_rc", "?")}
    kf_path = os.path.join(rd, "keyframes.txt")
    if not os.path.exists(kf_path):
        res["error"] = "no keyframes.txt (driver rc %s)" % res["driver_rc"]
        return res
    kfs = read_keyframes(kf_path)
    res["keyframes"] = len(kfs)
    maps = {}
    for k in kfs:
        maps.setdefault(k["map"], []).append(k)
    res["maps"] = len(maps)

    queries = cands = cands_true = cands_near = 0
    # Loop (the query's own map) and merge (another map) candidates: [all, false], near misses not false.
    by_kind = {"loop": [0, 0], "merge": [0, 0]}
    lap_cands, lap_true, lap_near = [0] * laps, [0] * laps, [0] * laps
    verdicts = {"loop": [0, 0], "merge": [0, 0], "relocalisation": [0, 0]}  # kind -> [all, accepted]
    accepted = {"loop": [], "merge": []}
    relocs = []
    attempts = attempt_cands = 0
    with open(os.path.join(rd, "events.txt")) as f:
        for line in f:
            line = line.strip()
            m = CAND_RE.match(line)
            if m:
                queries += 1
                qi = frames.index(float(m.group(3)))
                lap = min(laps - 1, qi * laps // max(1, len(gt)))
                for grp, kind in ((5, "loop"), (7, "merge")):
                    for t in filter(None, m.group(grp).split(",")):
                        ci = frames.index(float(t))
                        ok = true_pair(gt, qi, ci)[0]
                        near = near_miss(gt, qi, ci)
                        by_kind[kind][0] += 1
                        by_kind[kind][1] += not ok and not near
                        cands += 1
                        cands_true += ok
                        cands_near += near
                        lap_cands[lap] += 1
                        lap_true[lap] += ok
                        lap_near[lap] += near
                continue
            m = VERDICT_RE.match(line) or RELOC_VERDICT_RE.match(line)
            if m:
                kind = m.group(1) if line.startswith("verdict loop") or line.startswith("verdict merge") \
                    else "relocalisation"
                outcome = m.group(2) if kind != "relocalisation" else m.group(1)
                verdicts[kind][0] += 1
                verdicts[kind][1] += outcome == "accepted"
                continue
            m = PAIR_RE.match(line)
            if m:
                a, b = frames.index(float(m.group(4))), frames.index(float(m.group(7)))
                ok, d, ang = true_pair(gt, a, b)
                accepted[m.group(1)].append({"kf": int(m.group(2)), "frame": a, "matched_kf": int(m.group(5)),
                                              "matched_frame": b, "true": ok, "dist_m": d, "angle_deg": ang})
                continue
            m = RELOC_RE.match(line)
            if m:
                relocs.append(frames.index(float(m.group(2))))
                continue
            m = ATTEMPT_RE.match(line)
            if m:
                attempts += 1
                attempt_cands += int(m.group(3))
    res.update({"queries": queries, "candidates": cands, "candidates_true": cands_true,
                "candidates_near": cands_near, "candidates_by_kind": by_kind, "lap_candidates": lap_cands, "lap_candidates_true": lap_true,
                "lap_candidates_near": lap_near, "verdicts": verdicts,
                "loops": accepted["loop"],
                "merges": accepted["merge"], "relocalisations": relocs,
                "reloc_attempts": attempts, "reloc_attempt_candidates": attempt_cands,
                "frames_lost": int(counters.get("frames_lost", "0"))})
    if counters.get("humem") == "1":
        res["humem_answered"] = int(counters.get("humem_loop_answered", "0"))
        res["humem_queries"] = int(counters.get("humem_loop_queries", "0"))
        res["humem_pose_updates"] = int(counters.get("humem_pose_updates", "0"))
        if "humem_verdicts_reported" in counters:
            res["humem_verdicts_reported"] = int(counters["humem_verdicts_reported"])

    # Keyframe ATE (monocular: Sim3 alignment) of every map of at least 3
    # keyframes, each aligned on its own: reported for the largest map, and
    # as the RMSE over all their keyframes. A run that ends in several maps
    # has short maps that drift little, so compare ATEs of runs with the
    # same number of maps (or the pooled one together with "maps at end").
    ate = {}
    for map_id, m in maps.items():
        if len(m) >= 3:
            est = np.array([k["p"] for k in m])
            ref = np.array([gt[k["index"]][1] for k in m])
            ate[map_id] = umeyama_rmse(est, ref)
    big = max(maps, key=lambda map_id: len(maps[map_id]))
    res["ate_map_keyframes"] = len(maps[big])
    if big in ate:
        res["ate_m"] = ate[big]
    if ate:
        n = sum(len(maps[map_id]) for map_id in ate)
        res["ate_all_m"] = math.sqrt(sum(e ** 2 * len(maps[map_id]) for map_id, e in ate.items()) / n)
        res["ate_all_keyframes"] = n

    if is_humem(res["mode"]):
        r = store_check(os.path.join(rd, "store.jsonl"), kfs)
        res["store_ok"], res["store"] = r[0], r[1]
        if len(r) > 2:
            res["store_detail"] = r[2]
    return res


def fmt_pairs(pairs):
    return "%d (%d)" % (len(pairs), sum(p["true"] for p in pairs))


def fmt_laps(r):
    """Candidate precision per lap: "true/judged" of each lap (near misses left out), "—" for a lap without any."""
    return ", ".join("%d/%d" % (t, n - m) if n - m else "—"
                     for t, n, m in zip(r["lap_candidates_true"], r["lap_candidates"], r["lap_candidates_near"]))


def fmt_verdicts(r):
    """ORB-SLAM3's verdicts on candidates (loop + merge, relocalisation), accepted, and reported to HuMem."""
    v = r["verdicts"]
    lm = [v["loop"][0] + v["merge"][0], v["loop"][1] + v["merge"][1]]
    text = "%d (%d) + reloc %d (%d)" % (lm[0], lm[1], v["relocalisation"][0], v["relocalisation"][1])
    if "humem_verdicts_reported" in r:
        text += " [%d]" % r["humem_verdicts_reported"]
    return text


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--runs-dir", required=True, nargs="+",
                    help="run folders of run.sh; several (batches) make one table")
    ap.add_argument("--laps", type=int, default=3,
                    help="passes over the route: frames split into this many equal parts by index (default 3)")
    ap.add_argument("--json", help="also write the results here (default: results.json in the first RUNS)")
    a = ap.parse_args()
    gt = load_gt(a.dataset)
    frames = Frames(gt)
    laps = max(1, a.laps)
    results = []
    for batch, runs_dir in enumerate(a.runs_dir, 1):
        dirs = sorted(d for d in os.listdir(runs_dir) if os.path.exists(os.path.join(runs_dir, d, "run.txt")))
        for d in dirs:
            r = evaluate_run(os.path.join(runs_dir, d), gt, frames, laps)
            r["batch"] = batch
            if len(a.runs_dir) > 1:
                r["run"] = "%d.%s" % (batch, r["run"])
            results.append(r)

    def order(r):
        mode = r["mode"]
        rank = 0 if mode == "humem" else 1 if is_humem(mode) else 2
        run = [int(x) if x.isdigit() else 0 for x in str(r["run"]).split(".")]
        return (rank, mode, run)

    results.sort(key=order)

    print("| run | keyframes | frames lost | loop queries | candidates to geometric verification (true, near miss) "
          "| candidate precision per lap | verdicts (accepted) [reported to HuMem] | loops (true) "
          "| merges (true) | relocalisations (of attempts) | maps at end | KF ATE, Sim3 RMSE (largest map) "
          "| KF ATE (every map) | store = ORB-SLAM3 |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in results:
        name = "%s %s" % ("HuMem" if r["mode"] == "humem" else "DBoW2" if r["mode"] == "dbow2"
                          else "HuMem " + r["mode"][len("humem-"):] if is_humem(r["mode"]) else r["mode"], r["run"])
        if "error" in r:
            print("| %s | %s |  |  |  |  |  |  |  |  |  |  |  |  |" % (name, r["error"]))
            continue
        q = str(r["queries"])
        if "humem_answered" in r:
            q += " (answered %d)" % r["humem_answered"]
        ate = "%.2f m (%d KFs)" % (r["ate_m"], r["ate_map_keyframes"]) if "ate_m" in r else "—"
        ate_all = "%.2f m (%d KFs)" % (r["ate_all_m"], r["ate_all_keyframes"]) if "ate_all_m" in r else "—"
        reloc = "%d of %d" % (len(r["relocalisations"]), r["reloc_attempts"])
        print("| %s | %d | %d | %s | %d (%d, %d) | %s | %s | %s | %s | %s | %d | %s | %s | %s |" % (
            name, r["keyframes"], r["frames_lost"], q, r["candidates"], r["candidates_true"], r["candidates_near"],
            fmt_laps(r), fmt_verdicts(r),
            fmt_pairs(r["loops"]),
            fmt_pairs(r["merges"]), reloc, r["maps"], ate, ate_all, r.get("store", "—")))
    print()
    print("Per mode, all runs (precision: true / candidates, near misses left out; per batch where there are "
          "several; ATE: median keyframe ATE of the runs that ended in one map):")
    print()
    print("| mode | runs | accepted loops and merges (false) | candidates (true, near miss) | candidate precision "
          "| per batch | loop candidates (false) | merge candidates (false) | relocalisations | runs ending in one map "
          "| median one-map KF ATE | median frames lost | store = ORB-SLAM3 |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    modes = []
    for r in results:
        if "error" not in r and r["mode"] not in modes:
            modes.append(r["mode"])
    for mode in modes:
        rs = [r for r in results if r["mode"] == mode and "error" not in r]
        acc = [p for r in rs for p in r["loops"] + r["merges"]]
        one = sorted(r["ate_m"] for r in rs if r["maps"] == 1 and "ate_m" in r)
        med = "%.2f m (%.2f-%.2f)" % (float(np.median(one)), one[0], one[-1]) if one else "—"
        stores = "%d of %d" % (sum(bool(r.get("store_ok")) for r in rs), len(rs)) if is_humem(mode) else "—"
        total = [sum(r[k] for r in rs) for k in ("candidates_true", "candidates", "candidates_near")]
        batches = sorted({r["batch"] for r in rs})
        per_batch = ", ".join(precision(*[sum(r[k] for r in rs if r["batch"] == b)
                                          for k in ("candidates_true", "candidates", "candidates_near")])
                              for b in batches) if len(batches) > 1 else "—"
        kinds = ["%d (%d)" % (sum(r["candidates_by_kind"][k][0] for r in rs), sum(r["candidates_by_kind"][k][1] for r in rs))
                 for k in ("loop", "merge")]
        print("| %s | %d | %d (%d) | %d (%d, %d) | %s | %s | %s | %s | %d | %d | %s | %g | %s |"
              % (mode, len(rs), len(acc), sum(not p["true"] for p in acc), total[1], total[0], total[2],
                 precision(*total), per_batch, kinds[0], kinds[1], sum(len(r["relocalisations"]) for r in rs),
                 len(one), med,
                 float(np.median([r["frames_lost"] for r in rs])), stores))
    print()
    print("Accepted loops and merges (source frames; ground-truth distance and angle between them):")
    for r in results:
        for kind in ("loops", "merges"):
            for p in r.get(kind, []):
                print("- %s %s: %s KF %d (frame %d) ~ KF %d (frame %d): %.1f m, %.0f deg -> %s" % (
                    r["mode"], r["run"], kind[:-1], p["kf"], p["frame"], p["matched_kf"], p["matched_frame"],
                    p["dist_m"], p["angle_deg"], "true" if p["true"] else "FALSE"))
    for r in results:
        if r.get("reloc_attempts"):
            print("- %s %s: %d frames lost; %d relocalisation attempts with %d candidates in all; relocalised at "
                  "frames %s" % (r["mode"], r["run"], r["frames_lost"], r["reloc_attempts"],
                                 r["reloc_attempt_candidates"],
                                 ", ".join(str(i) for i in r["relocalisations"]) or "none"))
        if r.get("store_detail") and not r.get("store_ok"):
            print("- %s %s: store check %s" % (r["mode"], r["run"], json.dumps(r["store_detail"])))
    out = a.json or os.path.join(a.runs_dir[0], "results.json")
    with open(out, "w") as f:
        json.dump(results, f, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    return 0


if __name__ == "__main__":
    sys.exit(main())
