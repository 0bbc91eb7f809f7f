//! `humem eval --replay-verdicts`: the data set streamed as the ORB-SLAM3
//! plugin streams it, with the ground truth standing in for geometric
//! verification, once without verdicts and once with them.
//!
//! Every frame is stored as a keyframe as it comes and then asked about
//! (a loop: `SCOPE_SAME_MAP` with the data set's frame gap; pairs: the
//! references are stored first, then each query frame is stored and asked
//! about against them). The candidates above the operating point (the
//! store's threshold when the query was asked, which its verdicts may have
//! raised (`vpr.verdicts.adapt_threshold`; the configured one without
//! verdicts), and `max_candidates` of `[vpr]`) are what a SLAM system would
//! verify:
//! each one is "accepted" when the ground truth calls it a true place and
//! "rejected" otherwise, and a configurable share of the true places is
//! rejected all the same (`--wrong-rejections`, geometry's misses under
//! appearance change), drawn from a seeded generator. With verdicts on, each
//! verdict is recorded in the index exactly as the store records a
//! `ReportVerification`, and the next queries are ranked through the
//! service's own query path, which applies them.
//!
//! Keyframe poses are the data set's poses where it has them (a map already
//! corrected by its loop closures). Where it has none, the frames stand
//! along a line at the spacing the ground truth implies (a pass over a
//! place is as many frames long as 2 × 5 m, the truth's radius, cover):
//! odometry that is locally right and never corrected, so a revisit is
//! never near its first visit by pose — the pessimistic case for the
//! verdicts' place tests. A line is no odometry the drift envelope
//! ([`drift`]) could judge (every revisit lies the whole path away), so
//! such a replay turns the envelope off. `--replay-pose-drift` sends the
//! poses as a drifting odometry would ([`pose_drift`](super::pose_drift)),
//! and the table shows the envelope's `r` of the true and the false
//! candidates sent.
//!
//! Results are grouped by visit: 1 = the first time at a place (a loop
//! query without an earlier true place, or a pairs query without a match),
//! 2 = one earlier pass over it, and so on (the earlier passes are the runs
//! of the query's true places separated by more than half the frame gap).

use std::collections::BTreeMap;

use anyhow::Context;

use super::dataset::{self, Dataset};
use super::metrics;
use super::precision::{self, OperatingPoint, ScoredQuery};
use super::replay_rows::{FalseAlarm, ReplayRow, TrueAndFalse, SPREAD_OF_TOP};
use super::truth::Kind;
use humem_core::index::Index;
use humem_core::keyframe::{Features, Pose, SemanticKeyframe, SessionKey};
use humem_core::synthetic::Rng;
use humem_core::verdict::{Verdict, VerificationKind};
use humem_core::vpr::drift;
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::feedback::squared_distance;
use humem_core::vpr::feedback::VerdictParams;
use humem_core::vpr::params::{Layers, VprParams};
use humem_server::pipeline::query;
use humem_server::pipeline::request::{QueryKind, QuerySpec};

/// Options of the replay.
#[derive(Debug, Clone, Copy)]
pub struct ReplayOptions {
    /// Share of true places that geometry rejects all the same, in [0, 1].
    pub wrong_rejections: f64,
    /// Seed of the draws of those rejections.
    pub seed: u64,
    /// Factor on every stored position (1: the data set's metres).
    pub pose_scale: f64,
    /// Drift of the poses sent, as a share of the path
    /// ([`pose_drift`](super::pose_drift)); 0: the data set's poses.
    pub pose_drift: f64,
}

/// A further pass with other verdict settings (`--replay-variant
/// NAME:key=value,…`, keys of `[vpr.verdicts]`), to compare settings on
/// one's own data in one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Variant {
    /// The pass's name in the table.
    pub name: String,
    /// `key = value` pairs applied over the configured settings.
    pub settings: Vec<(String, String)>,
}

impl std::str::FromStr for Variant {
    type Err = String;

    fn from_str(s: &str) -> Result<Variant, String> {
        let (name, rest) = s
            .split_once(':')
            .ok_or_else(|| format!("{s:?}: expected NAME:key=value,…"))?;
        let settings = rest
            .split(',')
            .filter(|kv| !kv.trim().is_empty())
            .map(|kv| {
                kv.split_once('=')
                    .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
                    .ok_or_else(|| format!("{kv:?}: expected key=value"))
            })
            .collect::<Result<_, _>>()?;
        Ok(Variant {
            name: name.trim().to_string(),
            settings,
        })
    }
}

impl Variant {
    /// `base` with this variant's settings (keys of `[vpr.verdicts]` and
    /// `max_drift_ratio`), checked.
    pub fn apply(&self, base: &VprParams) -> anyhow::Result<VprParams> {
        let mut vpr = base.clone();
        let p = &mut vpr.verdicts;
        for (key, value) in &self.settings {
            let bad = || {
                anyhow::anyhow!(
                    "--replay-variant {}: {key} = {value:?} does not parse",
                    self.name
                )
            };
            match key.as_str() {
                "enabled" => p.enabled = value.parse().map_err(|_| bad())?,
                "radius_steps" => p.radius_steps = value.parse().map_err(|_| bad())?,
                "radius_m" => p.radius_m = Some(value.parse().map_err(|_| bad())?),
                "max_penalty" => p.max_penalty = value.parse().map_err(|_| bad())?,
                "support_gain" => p.support_gain = value.parse().map_err(|_| bad())?,
                "place_graph" => p.place_graph = value.parse().map_err(|_| bad())?,
                "half_life_hours" => p.half_life_hours = value.parse().map_err(|_| bad())?,
                "adapt_threshold" => p.adapt_threshold = value.parse().map_err(|_| bad())?,
                "target_precision" => p.target_precision = value.parse().map_err(|_| bad())?,
                "geometry_miss_rate" => p.geometry_miss_rate = value.parse().map_err(|_| bad())?,
                "min_verdicts" => p.min_verdicts = value.parse().map_err(|_| bad())?,
                "max_threshold_raise" => {
                    p.max_threshold_raise = value.parse().map_err(|_| bad())?
                }
                "max_drift_ratio" => vpr.max_drift_ratio = value.parse().map_err(|_| bad())?,
                other => anyhow::bail!(
                    "--replay-variant {}: no setting {other:?} (max_drift_ratio, or of [vpr.verdicts]: enabled, radius_steps, radius_m, max_penalty, support_gain, place_graph, half_life_hours, adapt_threshold, target_precision, geometry_miss_rate, min_verdicts, max_threshold_raise)",
                    self.name
                ),
            }
        }
        vpr.validate()
            .map_err(|e| anyhow::anyhow!("--replay-variant {}: {e}", self.name))?;
        Ok(vpr)
    }
}

/// A keyframe of the stream: as the evaluation stores one, at `pose`.
fn keyframe(robot: &str, index: usize, features: &Features, pose: Pose) -> SemanticKeyframe {
    SemanticKeyframe {
        pose,
        ..super::keyframes::stored(robot, index, features)
    }
}

/// Metres between frames on the stand-in line: the ground truth's
/// diameter (2 × 5 m) over the median number of frames in one pass of a
/// query's true places; 1 m without any.
pub fn line_spacing(dataset: &Dataset) -> f64 {
    let gap = dataset.min_frame_gap;
    let mut per_pass: Vec<f64> = dataset
        .matches
        .values()
        .filter(|m| !m.is_empty())
        .map(|m| m.len() as f64 / (visit_of(Some(m), gap) - 1) as f64)
        .collect();
    if per_pass.is_empty() {
        return 1.0;
    }
    per_pass.sort_by(f64::total_cmp);
    (10.0 / per_pass[per_pass.len() / 2]).clamp(0.1, 10.0)
}

/// The data set's poses of `folder` (`true`), or the line at `spacing`
/// metres (`false`).
fn poses_or_line(
    dir: &std::path::Path,
    folder: &str,
    len: usize,
    spacing: f64,
) -> anyhow::Result<(Vec<Pose>, bool)> {
    Ok(match dataset::poses(dir, folder)? {
        Some(poses) if poses.len() == len => (
            poses
                .iter()
                .map(|p| Pose {
                    translation: [p.t.x, p.t.y, p.t.z],
                    rotation: [p.r.w, p.r.i, p.r.j, p.r.k],
                })
                .collect(),
            true,
        ),
        Some(poses) => anyhow::bail!(
            "{}: {} poses for {len} images in {folder}/",
            dir.display(),
            poses.len()
        ),
        None => (
            (0..len)
                .map(|i| Pose {
                    translation: [i as f64 * spacing, 0.0, 0.0],
                    ..Pose::default()
                })
                .collect(),
            false,
        ),
    })
}

/// Which visit of its place a query is: 1 + the earlier passes over it.
pub fn visit_of(matches: Option<&Vec<usize>>, gap: usize) -> usize {
    let Some(m) = matches.filter(|m| !m.is_empty()) else {
        return 1;
    };
    let mut sorted = m.clone();
    sorted.sort_unstable();
    let split = (gap / 2).max(1);
    1 + 1 + sorted.windows(2).filter(|w| w[1] - w[0] > split).count()
}

/// Robot of the drive (a loop's frames, a pairs set's queries).
pub(crate) const ROBOT: &str = "drive";
/// Robot of a pairs set's references.
pub(crate) const REFERENCE_ROBOT: &str = "reference";

/// Where a pass stores frames, asks and reports: the in-process index
/// ([`LocalStream`]) or a running service (`remote`). A pass starts on an
/// empty stream.
pub(crate) trait ReplayStream {
    /// Stores frame `index` of `robot` ([`ROBOT`] or [`REFERENCE_ROBOT`]),
    /// in map 0 of its one session, at `pose`.
    async fn store(&mut self, robot: &str, index: usize, pose: Pose) -> anyhow::Result<()>;
    /// Asks about stored frame `q` of the drive, with no threshold: the
    /// ranked `(keyframe id, score)` of the candidate robot's keyframes,
    /// and the store's operating threshold at that moment (what a query
    /// naming none would have been answered at).
    async fn ask(&mut self, q: usize, pairs: bool, gap: usize) -> anyhow::Result<Asked>;
    /// Reports the verdict on candidate `candidate` of `robot` for query
    /// frame `q`.
    async fn report(
        &mut self,
        q: usize,
        robot: &str,
        candidate: u64,
        accepted: bool,
        score: f32,
    ) -> anyhow::Result<()>;
}

/// One query's answer in a replay.
#[derive(Debug, Clone, Default)]
pub(crate) struct Asked {
    /// `(keyframe id, score)`, best first.
    pub ranked: Vec<(u64, f32)>,
    /// The store's operating threshold when it was asked.
    pub threshold: f32,
}

/// The in-process stream: the service's own index and query path.
pub(crate) struct LocalStream<'a> {
    index: Index,
    params: VprParams,
    references: &'a [Features],
    queries: &'a [Features],
}

impl ReplayStream for LocalStream<'_> {
    async fn store(&mut self, robot: &str, index: usize, pose: Pose) -> anyhow::Result<()> {
        let features = if robot == REFERENCE_ROBOT {
            &self.references[index]
        } else {
            &self.queries[index]
        };
        self.index.upsert(keyframe(robot, index, features, pose));
        Ok(())
    }

    async fn ask(&mut self, q: usize, pairs: bool, gap: usize) -> anyhow::Result<Asked> {
        let spec = QuerySpec {
            session: SessionKey {
                robot_id: ROBOT.into(),
                session_id: String::new(),
            },
            map_id: None,
            frame_id: None,
            keyframe_id: Some(q as u64),
            observation: None,
            predecessor_ids: Vec::new(),
            scope: if pairs {
                Scope::Listed {
                    robot_ids: vec![REFERENCE_ROBOT.into()],
                    maps: Vec::new(),
                }
            } else {
                Scope::SameMap
            },
            readable_robots: None,
            min_frame_gap: gap as u64,
            top_n: self.params.top_k,
            threshold: Some(0.0),
            layers: Layers::FULL,
            kind: QueryKind::LoopClosure,
            exact: false,
        };
        let outcome = query::run(&self.index, &self.params, &spec)
            .with_context(|| format!("ranking query {q}"))?;
        Ok(Asked {
            ranked: outcome
                .candidates
                .iter()
                .map(|c| (c.key.keyframe_id, c.score))
                .collect(),
            threshold: outcome.operating_point.threshold,
        })
    }

    async fn report(
        &mut self,
        q: usize,
        robot: &str,
        candidate: u64,
        accepted: bool,
        score: f32,
    ) -> anyhow::Result<()> {
        let session = |robot: &str| SessionKey {
            robot_id: robot.into(),
            session_id: String::new(),
        };
        self.index.record_verdict(Verdict {
            query: session(ROBOT).keyframe(q as u64),
            candidate: session(robot).keyframe(candidate),
            kind: VerificationKind::Loop,
            accepted,
            relative: None,
            score: Some(score),
            inliers: 0,
            reported_at: humem_core::verdict::unix_now(),
        });
        Ok(())
    }
}

/// The poses a replay stores its frames at: `(references, queries)`.
pub type StreamPoses = (Vec<Pose>, Vec<Pose>);

/// The keyframe poses of a data set: `(references, queries)` (for a loop,
/// the same), the data set's own or the stand-in line, drifted by
/// `options.pose_drift` and scaled by `options.pose_scale`; and whether
/// they are the data set's own (the stand-in line is no odometry the drift
/// envelope could judge: every revisit lies the whole path away).
pub fn replay_poses(
    dir: &std::path::Path,
    dataset: &Dataset,
    options: &ReplayOptions,
) -> anyhow::Result<(StreamPoses, bool)> {
    let spacing = line_spacing(dataset);
    let sent = |poses: Vec<Pose>, seed: u64| -> Vec<Pose> {
        super::pose_drift::drifted(&poses, options.pose_drift, seed)
            .into_iter()
            .map(|mut p| {
                p.translation = p.translation.map(|t| t * options.pose_scale);
                p
            })
            .collect()
    };
    // The drift's own seeds, apart from the rejections' draws.
    let seed = options.seed ^ 0xD21F_7000;
    Ok(match dataset.kind {
        Kind::Loop => {
            let (p, own) = poses_or_line(dir, "sequence", dataset.references.len(), spacing)?;
            let p = sent(p, seed);
            ((p.clone(), p), own)
        }
        Kind::Pairs => {
            let (r, _) = poses_or_line(dir, "reference", dataset.references.len(), spacing)?;
            let (q, own) = poses_or_line(dir, "query", dataset.queries.len(), spacing)?;
            ((sent(r, seed), sent(q, seed + 1)), own)
        }
    })
}

/// Streams the data set in-process once without verdicts, once with the
/// configured verdict settings and once per variant, and returns the
/// table's rows. `references` and `queries` are the perceived features (for
/// a loop, the same frames).
pub async fn replay(
    params: &VprParams,
    dir: &std::path::Path,
    dataset: &Dataset,
    references: &[Features],
    queries: &[Features],
    options: ReplayOptions,
    variants: &[Variant],
) -> anyhow::Result<Vec<ReplayRow>> {
    let point = OperatingPoint {
        threshold: params.threshold(),
        max_candidates: params.max_candidates,
    };
    let (poses, own_poses) = replay_poses(dir, dataset, &options)?;
    let mut params = params.clone();
    if !own_poses {
        // The stand-in line is no odometry: the drift envelope is off.
        params.max_drift_ratio = drift::OFF_RATIO;
    }
    let with_verdicts = |enabled| VprParams {
        verdicts: VerdictParams {
            enabled,
            ..params.verdicts.clone()
        },
        ..params.clone()
    };
    let mut passes = vec![
        ("without verdicts".to_string(), with_verdicts(false)),
        ("with verdicts".to_string(), with_verdicts(true)),
    ];
    for v in variants {
        passes.push((v.name.clone(), v.apply(&params)?));
    }
    let mut rows = Vec::new();
    for (pass, params) in passes {
        let report = params.verdicts.enabled;
        let dim = references.first().map_or(0, |f| f.descriptor.len());
        let mut stream = LocalStream {
            index: Index::new(dim),
            params,
            references,
            queries,
        };
        rows.extend(
            replay_pass(&mut stream, &pass, dataset, &poses, point, options, report).await?,
        );
    }
    Ok(rows)
}

/// One pass over the data set on `stream`: store, ask, and (if `report`)
/// report each candidate sent to verification; the pass's rows.
pub(crate) async fn replay_pass<S: ReplayStream>(
    stream: &mut S,
    pass: &str,
    dataset: &Dataset,
    (reference_poses, query_poses): &StreamPoses,
    point: OperatingPoint,
    options: ReplayOptions,
    report: bool,
) -> anyhow::Result<Vec<ReplayRow>> {
    let mut rng = Rng::new(options.seed);
    let pairs = dataset.kind == Kind::Pairs;
    let (candidate_robot, gap) = if pairs {
        for (i, pose) in reference_poses.iter().enumerate() {
            stream.store(REFERENCE_ROBOT, i, *pose).await?;
        }
        (REFERENCE_ROBOT, 0)
    } else {
        (ROBOT, dataset.min_frame_gap)
    };
    // Per visit: the scored queries, their rankings and wrong rejections.
    let mut groups: BTreeMap<usize, Group> = BTreeMap::new();
    let along = path_along(query_poses);
    let bar = super::progress::progress(query_poses.len(), pass);
    for (q, pose) in query_poses.iter().enumerate() {
        bar.inc(1);
        stream.store(ROBOT, q, *pose).await?;
        if !pairs && q < gap {
            continue; // nothing is eligible yet
        }
        let asked = stream.ask(q, pairs, gap).await?;
        // Without verdicts, the configured threshold: a store's adapted
        // one is the verdicts' doing.
        let threshold = if report {
            asked.threshold
        } else {
            point.threshold
        };
        let ranked = asked.ranked;
        let matches = dataset.matches.get(&q);
        let is_true = |id: u64| matches.is_some_and(|m| m.contains(&(id as usize)));
        let has_match = matches.is_some_and(|m| !m.is_empty());
        let group = groups.entry(visit_of(matches, gap)).or_default();
        if let Some(&(candidate, score)) = ranked.first().filter(|&&(_, s)| s > threshold) {
            let top: Vec<[f64; 3]> = ranked
                .iter()
                .take(SPREAD_OF_TOP)
                .map(|&(id, _)| reference_poses[id as usize].translation)
                .collect();
            group.spreads.push(is_true(candidate), spread(&top));
            if !has_match {
                let at = |poses: &[Pose], i: u64| poses[i as usize].translation;
                group.false_alarms.push(FalseAlarm {
                    query: q,
                    candidate,
                    score,
                    threshold,
                    distance: squared_distance(
                        at(query_poses, q as u64),
                        at(reference_poses, candidate),
                    )
                    .sqrt(),
                });
            }
        }
        group.scored.push(ScoredQuery {
            ranked: ranked.iter().map(|&(id, s)| (s, is_true(id))).collect(),
            has_match,
            threshold: Some(threshold),
        });
        if let Some(m) = matches.filter(|m| !m.is_empty()) {
            group.answers.push((
                ranked.iter().map(|&(id, _)| id as usize).collect(),
                m.clone(),
            ));
        }
        let sent = ranked
            .iter()
            .filter(|&&(_, s)| s > threshold)
            .take(point.max_candidates);
        for &(id, score) in sent {
            let truth = is_true(id);
            if !pairs {
                let distance = squared_distance(
                    query_poses[q].translation,
                    query_poses[id as usize].translation,
                )
                .sqrt();
                let path = (along[q] - along[id as usize]).abs();
                let r = if path > 0.0 { distance / path } else { 0.0 };
                group.ratios.push(truth, r);
            }
            // Drawn for every candidate sent, in every pass alike.
            let missed = (rng.next() as f64 / u64::MAX as f64) < options.wrong_rejections;
            if truth && missed {
                group.wrong_rejections += 1;
            }
            if report {
                stream
                    .report(q, candidate_robot, id, truth && !missed, score)
                    .await?;
            }
        }
    }
    bar.finish_and_clear();
    let mut rows = Vec::new();
    let mut all = Group::default();
    for (visit, group) in &groups {
        rows.push(group.row(pass, &visit.to_string(), point));
        all.scored.extend(group.scored.iter().cloned());
        all.answers.extend(group.answers.iter().cloned());
        all.wrong_rejections += group.wrong_rejections;
        all.false_alarms.extend(group.false_alarms.iter().cloned());
        all.ratios.extend(&group.ratios);
        all.spreads.extend(&group.spreads);
    }
    all.false_alarms.sort_by_key(|f| f.query);
    rows.push(all.row(pass, "all", point));
    Ok(rows)
}

/// The queries of one visit class.
#[derive(Debug, Default)]
struct Group {
    scored: Vec<ScoredQuery>,
    answers: Vec<(Vec<usize>, Vec<usize>)>,
    wrong_rejections: usize,
    false_alarms: Vec<FalseAlarm>,
    ratios: TrueAndFalse,
    spreads: TrueAndFalse,
}

/// Root mean square distance of `positions` from their centroid.
fn spread(positions: &[[f64; 3]]) -> f64 {
    if positions.is_empty() {
        return 0.0;
    }
    let n = positions.len() as f64;
    let mut centre = [0.0; 3];
    for p in positions {
        for (c, x) in centre.iter_mut().zip(p) {
            *c += x / n;
        }
    }
    let square: f64 = positions.iter().map(|&p| squared_distance(p, centre)).sum();
    (square / n).sqrt()
}

/// The path driven up to each pose: the running sum of the distances
/// between consecutive poses.
fn path_along(poses: &[Pose]) -> Vec<f64> {
    let mut walked = 0.0;
    let mut along = Vec::with_capacity(poses.len());
    for (i, pose) in poses.iter().enumerate() {
        if i > 0 {
            walked += squared_distance(poses[i - 1].translation, pose.translation).sqrt();
        }
        along.push(walked);
    }
    along
}

impl Group {
    fn row(&self, pass: &str, visit: &str, point: OperatingPoint) -> ReplayRow {
        let p = precision::precision(&self.scored, point);
        let r = metrics::retrieval(&self.answers);
        ReplayRow {
            pass: pass.into(),
            visit: visit.into(),
            queries: p.queries,
            with_match: p.with_match,
            false_alarm_rate: p.false_alarm_rate,
            false_alarms: p.false_no_match,
            recall_at_1: r.recall_at_1,
            recall_at_threshold: p.recall_at_threshold,
            candidate_precision: p.candidate_precision,
            candidates: p.candidates,
            wrong_rejections: self.wrong_rejections,
            false_alarm_list: self.false_alarms.clone(),
            drift_ratios: self.ratios.sorted(),
            top_spread: self.spreads.sorted(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay_rows::table;

    /// A stream whose answers are written out by the test, and which keeps
    /// what it was told: the accounting of [`replay_pass`] on its own.
    #[derive(Default)]
    struct Scripted {
        answers: BTreeMap<usize, Vec<(u64, f32)>>,
        stored: Vec<(String, usize)>,
        reported: Vec<(usize, u64, bool)>,
    }

    impl ReplayStream for Scripted {
        async fn store(&mut self, robot: &str, index: usize, _: Pose) -> anyhow::Result<()> {
            self.stored.push((robot.into(), index));
            Ok(())
        }

        async fn ask(&mut self, q: usize, _: bool, _: usize) -> anyhow::Result<Asked> {
            Ok(Asked {
                ranked: self.answers.get(&q).cloned().unwrap_or_default(),
                threshold: 0.36,
            })
        }

        async fn report(
            &mut self,
            q: usize,
            _: &str,
            candidate: u64,
            accepted: bool,
            _: f32,
        ) -> anyhow::Result<()> {
            self.reported.push((q, candidate, accepted));
            Ok(())
        }
    }

    /// Six frames along x, 1 m apart, a frame gap of 2. Frame 4 revisits
    /// frame 0; frames 2, 3 and 5 have no true place. Frame 3 is answered
    /// by frame 0 above the threshold (a false alarm, 3 m away), frame 2
    /// only below it, frame 5 by frame 1 (another false alarm, 4 m).
    #[tokio::test]
    async fn a_pass_counts_and_lists_the_false_alarms_and_reports_every_candidate_sent() {
        let dataset = Dataset {
            name: "scripted".into(),
            kind: Kind::Loop,
            queries: Vec::new(),
            references: Vec::new(),
            matches: BTreeMap::from([(4, vec![0])]),
            min_frame_gap: 2,
            truth_source: "test".into(),
        };
        let poses: Vec<Pose> = (0..6)
            .map(|i| Pose {
                translation: [i as f64, 0.0, 0.0],
                ..Pose::default()
            })
            .collect();
        let mut stream = Scripted {
            answers: BTreeMap::from([
                (2, vec![(0, 0.30)]),
                (3, vec![(0, 0.50), (1, 0.40)]),
                (4, vec![(0, 0.70), (1, 0.20)]),
                (5, vec![(1, 0.37)]),
            ]),
            ..Scripted::default()
        };
        let point = OperatingPoint {
            threshold: 0.36,
            max_candidates: 5,
        };
        let options = ReplayOptions {
            wrong_rejections: 0.0,
            seed: 1,
            pose_scale: 1.0,
            pose_drift: 0.0,
        };
        let rows = replay_pass(
            &mut stream,
            "with verdicts",
            &dataset,
            &(poses.clone(), poses),
            point,
            options,
            true,
        )
        .await
        .unwrap();
        assert_eq!(stream.stored.len(), 6, "every frame is stored");
        // Sent: 3 → 0 and 3 → 1 (both above 0.36), 4 → 0, 5 → 1.
        assert_eq!(
            stream.reported,
            vec![(3, 0, false), (3, 1, false), (4, 0, true), (5, 1, false)]
        );
        let first = rows.iter().find(|r| r.visit == "1").unwrap();
        assert_eq!((first.queries, first.false_alarms), (3, 2));
        let all = rows.iter().find(|r| r.visit == "all").unwrap();
        assert_eq!(all.candidates, 4);
        assert_eq!(all.recall_at_threshold, 1.0);
        assert_eq!(
            all.false_alarm_list,
            vec![
                FalseAlarm {
                    query: 3,
                    candidate: 0,
                    score: 0.50,
                    threshold: 0.36,
                    distance: 3.0,
                },
                FalseAlarm {
                    query: 5,
                    candidate: 1,
                    score: 0.37,
                    threshold: 0.36,
                    distance: 4.0,
                },
            ]
        );
        // On a line every candidate lies the whole path away: r = 1.
        assert_eq!(all.drift_ratios.true_candidates, vec![1.0]);
        assert_eq!(all.drift_ratios.false_candidates, vec![1.0; 3]);
        // Answered: 3 (top 0, false) and 4 (top 0, true) with frames 0
        // and 1 in their top five (0.5 from their centre), 5 (top 1,
        // false) with frame 1 alone.
        assert_eq!(all.top_spread.true_candidates, vec![0.5]);
        assert_eq!(all.top_spread.false_candidates, vec![0.0, 0.5]);
        let printed = table(&rows);
        assert!(
            printed.contains("- with verdicts: 3 → 0: 0.500, 3.0 m; 5 → 1: 0.370, 4.0 m"),
            "{printed}"
        );
        assert!(
            printed.contains("| with verdicts | 1 | 1.000 / 1.000 / 1.000 / 1.000 | 3 |"),
            "{printed}"
        );
    }

    /// A variant sets the drift envelope's bound beside the verdicts'
    /// settings, and a bad value names itself.
    #[test]
    fn a_variant_sets_the_drift_bound_and_verdict_settings() {
        let v: Variant = "open:max_drift_ratio=1,max_penalty=0.5".parse().unwrap();
        let p = v.apply(&VprParams::default()).unwrap();
        assert_eq!(p.max_drift_ratio, 1.0);
        assert_eq!(p.verdicts.max_penalty, 0.5);
        let bad: Variant = "bad:max_drift_ratio=0".parse().unwrap();
        let e = bad.apply(&VprParams::default()).unwrap_err().to_string();
        assert!(e.contains("max_drift_ratio"), "{e}");
    }

    #[test]
    fn visits_count_the_earlier_passes() {
        assert_eq!(visit_of(None, 100), 1);
        assert_eq!(visit_of(Some(&vec![]), 100), 1);
        assert_eq!(visit_of(Some(&vec![3, 4, 5]), 100), 2);
        // Two runs of true places 140 frames apart: the third visit.
        assert_eq!(visit_of(Some(&vec![150, 5, 6, 151]), 100), 3);
        // A gap of exactly half the frame gap stays one pass.
        assert_eq!(visit_of(Some(&vec![0, 50]), 100), 2);
    }
}
