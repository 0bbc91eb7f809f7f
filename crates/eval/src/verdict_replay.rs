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

use std::collections::{BTreeMap, HashMap};

use anyhow::Context;

use super::dataset::{self, Dataset};
use super::metrics;
use super::precision::{self, OperatingPoint, ScoredQuery};
use super::replay_rows::{FalseAlarm, ReplayAnswer, ReplayRow, TrueAndFalse, SPREAD_OF_TOP};
use super::truth::Kind;
use humem_core::index::Index;
use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::synthetic::Rng;
use humem_core::verdict::{Verdict, VerificationKind};
use humem_core::vpr::drift;
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::feedback::squared_distance;
use humem_core::vpr::feedback::VerdictParams;
use humem_core::vpr::params::{Layers, VprParams};

pub use super::replay_steps::StreamPoses;
pub(crate) use super::replay_steps::{dataset_steps, Step, REFERENCE_ROBOT, ROBOT};
use super::replay_variant::Variant;
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

/// Where a pass stores keyframes, asks and reports: the in-process index
/// ([`LocalStream`]) or a running service (`remote`). A pass starts on an
/// empty stream.
pub(crate) trait ReplayStream {
    /// Stores image `image` of `robot` as keyframe `id` of map `map`, at `pose`.
    async fn store(
        &mut self,
        robot: &str,
        id: u64,
        image: usize,
        map: u64,
        pose: Pose,
    ) -> anyhow::Result<()>;
    /// Moves stored keyframe `id` of the drive to `pose` in map `map`.
    async fn move_to(&mut self, id: u64, map: u64, pose: Pose) -> anyhow::Result<()>;
    /// Erases stored keyframe `id` of the drive.
    async fn erase(&mut self, id: u64) -> anyhow::Result<()>;
    /// Asks about stored keyframe `q` of the drive, with no threshold: the
    /// ranked candidates of the candidate robot's keyframes, and the
    /// store's operating threshold at that moment (what a query naming
    /// none would have been answered at).
    async fn ask(&mut self, q: u64, pairs: bool, gap: usize) -> anyhow::Result<Asked>;
    /// Reports the verdict on candidate `candidate` of `robot` for query
    /// keyframe `q`.
    async fn report(
        &mut self,
        q: u64,
        robot: &str,
        candidate: u64,
        accepted: bool,
        score: f32,
    ) -> anyhow::Result<()>;
}

/// One candidate of a replay's answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Ranked {
    /// The candidate's keyframe id.
    pub id: u64,
    /// Its score.
    pub score: f32,
    /// The drift envelope's `r` (distance over path), for a candidate of
    /// the query's own map.
    pub drift_ratio: Option<f64>,
}

/// One query's answer in a replay.
#[derive(Debug, Clone, Default)]
pub(crate) struct Asked {
    /// The candidates, best first.
    pub ranked: Vec<Ranked>,
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

impl LocalStream<'_> {
    fn key(robot: &str, id: u64) -> KeyframeKey {
        KeyframeKey {
            robot_id: robot.into(),
            session_id: String::new(),
            keyframe_id: id,
        }
    }
}

impl ReplayStream for LocalStream<'_> {
    async fn store(
        &mut self,
        robot: &str,
        id: u64,
        image: usize,
        map: u64,
        pose: Pose,
    ) -> anyhow::Result<()> {
        let features = if robot == REFERENCE_ROBOT {
            &self.references[image]
        } else {
            &self.queries[image]
        };
        let mut stored = keyframe(robot, image, features, pose);
        stored.key.keyframe_id = id;
        stored.map_id = map;
        self.index.upsert(stored);
        Ok(())
    }

    async fn move_to(&mut self, id: u64, map: u64, pose: Pose) -> anyhow::Result<()> {
        self.index
            .update_pose(&Self::key(ROBOT, id), pose, Some(map));
        Ok(())
    }

    async fn erase(&mut self, id: u64) -> anyhow::Result<()> {
        self.index.remove(&Self::key(ROBOT, id));
        Ok(())
    }

    async fn ask(&mut self, q: u64, pairs: bool, gap: usize) -> anyhow::Result<Asked> {
        let spec = QuerySpec {
            session: SessionKey {
                robot_id: ROBOT.into(),
                session_id: String::new(),
            },
            map_id: None,
            frame_id: None,
            keyframe_id: Some(q),
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
                .map(|c| Ranked {
                    id: c.key.keyframe_id,
                    score: c.score,
                    drift_ratio: c.drift.map(|d| d.ratio()),
                })
                .collect(),
            threshold: outcome.operating_point.threshold,
        })
    }

    async fn report(
        &mut self,
        q: u64,
        robot: &str,
        candidate: u64,
        accepted: bool,
        score: f32,
    ) -> anyhow::Result<()> {
        self.index.record_verdict(Verdict {
            query: Self::key(ROBOT, q),
            candidate: Self::key(robot, candidate),
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
    let (poses, own_poses) = replay_poses(dir, dataset, &options)?;
    let mut params = params.clone();
    if !own_poses {
        // The stand-in line is no odometry: the drift envelope is off.
        params.max_drift_ratio = drift::OFF_RATIO;
    }
    let steps = dataset_steps(dataset, &poses);
    replay_steps(
        &params, dataset, references, queries, &steps, options, variants,
    )
    .await
}

/// Runs `steps` in-process once without verdicts, once with the configured
/// verdict settings and once per variant; the table's rows.
pub(crate) async fn replay_steps(
    params: &VprParams,
    dataset: &Dataset,
    references: &[Features],
    queries: &[Features],
    steps: &[Step],
    options: ReplayOptions,
    variants: &[Variant],
) -> anyhow::Result<Vec<ReplayRow>> {
    let point = OperatingPoint {
        threshold: params.threshold(),
        max_candidates: params.max_candidates,
    };
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
        passes.push((v.name.clone(), v.apply(params)?));
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
        rows.extend(replay_pass(&mut stream, &pass, dataset, steps, point, options, report).await?);
    }
    Ok(rows)
}

/// A keyframe a pass holds: its image, map and pose as last sent.
#[derive(Debug, Clone, Copy)]
struct Held {
    image: usize,
    map: u64,
    pose: Pose,
}

/// The keyframes one robot holds in a pass, by id and by image.
#[derive(Debug, Default)]
struct Holdings {
    by_id: HashMap<u64, Held>,
    by_image: HashMap<usize, u64>,
}

impl Holdings {
    fn insert(&mut self, id: u64, held: Held) {
        if let Some(old) = self.by_id.insert(id, held) {
            self.by_image.remove(&old.image);
        }
        self.by_image.insert(held.image, id);
    }

    fn remove(&mut self, id: u64) {
        if let Some(old) = self.by_id.remove(&id) {
            self.by_image.remove(&old.image);
        }
    }
}

/// A query judged by the ground truth of its image, against the keyframes
/// the pass holds where it may look.
struct Judged<'a> {
    /// The keyframes it may be answered with (and others, of other maps).
    pool: &'a Holdings,
    /// The query as held.
    query: Held,
    /// Images of its true places that the pool holds where it may look.
    matches: Vec<usize>,
}

impl<'a> Judged<'a> {
    fn new(dataset: &Dataset, pool: &'a Holdings, q: u64, query: Held, pairs: bool) -> Self {
        let matches = dataset
            .matches
            .get(&query.image)
            .into_iter()
            .flatten()
            .copied()
            .filter(|m| {
                pool.by_image
                    .get(m)
                    .is_some_and(|id| *id != q && (pairs || pool.by_id[id].map == query.map))
            })
            .collect();
        Judged {
            pool,
            query,
            matches,
        }
    }

    fn is_true(&self, id: u64) -> bool {
        self.pool
            .by_id
            .get(&id)
            .is_some_and(|h| self.matches.contains(&h.image))
    }

    /// Counts the answer `ranked` into `group`; the candidates sent to
    /// verification: `(id, true place, score)`.
    fn account(
        &self,
        group: &mut Group,
        visit: usize,
        ranked: &[Ranked],
        threshold: f32,
        point: OperatingPoint,
    ) -> Vec<(u64, bool, f32)> {
        let held_of = |id: u64| self.pool.by_id.get(&id);
        let has_match = !self.matches.is_empty();
        group.answered.push(ReplayAnswer {
            query: self.query.image,
            visit,
            threshold,
            ranked: ranked
                .iter()
                .map(|r| {
                    let image = held_of(r.id).map_or(usize::MAX, |h| h.image);
                    (image, r.score, r.drift_ratio, self.is_true(r.id))
                })
                .collect(),
        });
        if let Some(top) = ranked.first().filter(|r| r.score > threshold) {
            let positions: Vec<[f64; 3]> = ranked
                .iter()
                .take(SPREAD_OF_TOP)
                .filter_map(|r| held_of(r.id).map(|h| h.pose.translation))
                .collect();
            group.spreads.push(self.is_true(top.id), spread(&positions));
            if !has_match {
                let candidate = held_of(top.id);
                group.false_alarms.push(FalseAlarm {
                    query: self.query.image,
                    candidate: candidate.map_or(top.id, |h| h.image as u64),
                    score: top.score,
                    threshold,
                    distance: candidate.map_or(f64::NAN, |h| {
                        squared_distance(self.query.pose.translation, h.pose.translation).sqrt()
                    }),
                });
            }
        }
        group.scored.push(ScoredQuery {
            ranked: ranked
                .iter()
                .map(|r| (r.score, self.is_true(r.id)))
                .collect(),
            has_match,
            threshold: Some(threshold),
        });
        if has_match {
            group.answers.push((
                ranked
                    .iter()
                    .map(|r| held_of(r.id).map_or(usize::MAX, |h| h.image))
                    .collect(),
                self.matches.clone(),
            ));
        }
        let mut sent = Vec::new();
        for r in ranked
            .iter()
            .filter(|r| r.score > threshold)
            .take(point.max_candidates)
        {
            let truth = self.is_true(r.id);
            if let Some(ratio) = r.drift_ratio {
                group.ratios.push(truth, ratio);
            }
            sent.push((r.id, truth, r.score));
        }
        sent
    }
}

/// One pass of `steps` on `stream`: store, move, erase, ask, and (if
/// `report`) report each candidate sent to verification; the pass's rows.
/// A query's true places are those of its image's ground truth that the
/// stream holds where the query may look: the references of a pairs set,
/// or the keyframes of the query's own map.
pub(crate) async fn replay_pass<S: ReplayStream>(
    stream: &mut S,
    pass: &str,
    dataset: &Dataset,
    steps: &[Step],
    point: OperatingPoint,
    options: ReplayOptions,
    report: bool,
) -> anyhow::Result<Vec<ReplayRow>> {
    let mut rng = Rng::new(options.seed);
    let pairs = dataset.kind == Kind::Pairs;
    let (candidate_robot, gap) = if pairs {
        (REFERENCE_ROBOT, 0)
    } else {
        (ROBOT, dataset.min_frame_gap)
    };
    let mut drive = Holdings::default();
    let mut references = Holdings::default();
    // Per visit: the scored queries, their rankings and wrong rejections.
    let mut groups: BTreeMap<usize, Group> = BTreeMap::new();
    let asks = steps
        .iter()
        .filter(|s| matches!(s, Step::Ask { .. }))
        .count();
    let bar = super::progress::progress(asks, pass);
    for step in steps {
        match *step {
            Step::Store {
                robot,
                id,
                image,
                map,
                pose,
            } => {
                stream.store(robot, id, image, map, pose).await?;
                let held = Held { image, map, pose };
                if robot == REFERENCE_ROBOT {
                    references.insert(id, held);
                } else {
                    drive.insert(id, held);
                }
            }
            Step::Move { id, map, pose } => {
                stream.move_to(id, map, pose).await?;
                if let Some(held) = drive.by_id.get_mut(&id) {
                    held.map = map;
                    held.pose = pose;
                }
            }
            Step::Erase { id } => {
                stream.erase(id).await?;
                drive.remove(id);
            }
            Step::Ask { id: q } => {
                bar.inc(1);
                let Some(&query) = drive.by_id.get(&q) else {
                    continue; // erased before it was asked about
                };
                let asked = stream.ask(q, pairs, gap).await?;
                // Without verdicts, the configured threshold: a store's
                // adapted one is the verdicts' doing.
                let threshold = if report {
                    asked.threshold
                } else {
                    point.threshold
                };
                let pool = if pairs { &references } else { &drive };
                let judged = Judged::new(dataset, pool, q, query, pairs);
                let visit = visit_of(Some(&judged.matches), gap);
                let group = groups.entry(visit).or_default();
                let sent = judged.account(group, visit, &asked.ranked, threshold, point);
                for (id, truth, score) in sent {
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
        all.answered.extend(group.answered.iter().cloned());
    }
    all.false_alarms.sort_by_key(|f| f.query);
    all.answered.sort_by_key(|a| a.query);
    let mut row = all.row(pass, "all", point);
    row.answers = all.answered;
    rows.push(row);
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
    answered: Vec<ReplayAnswer>,
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
            answers: Vec::new(),
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
        answers: BTreeMap<u64, Vec<(u64, f32)>>,
        stored: Vec<(String, u64)>,
        reported: Vec<(u64, u64, bool)>,
    }

    impl ReplayStream for Scripted {
        async fn store(
            &mut self,
            robot: &str,
            id: u64,
            _: usize,
            _: u64,
            _: Pose,
        ) -> anyhow::Result<()> {
            self.stored.push((robot.into(), id));
            Ok(())
        }

        async fn move_to(&mut self, _: u64, _: u64, _: Pose) -> anyhow::Result<()> {
            Ok(())
        }

        async fn erase(&mut self, _: u64) -> anyhow::Result<()> {
            Ok(())
        }

        /// The scripted answer; on a line every candidate lies the whole
        /// path away (r = 1).
        async fn ask(&mut self, q: u64, _: bool, _: usize) -> anyhow::Result<Asked> {
            let ranked = self.answers.get(&q).cloned().unwrap_or_default();
            Ok(Asked {
                ranked: ranked
                    .into_iter()
                    .map(|(id, score)| Ranked {
                        id,
                        score,
                        drift_ratio: Some(1.0),
                    })
                    .collect(),
                threshold: 0.36,
            })
        }

        async fn report(
            &mut self,
            q: u64,
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
        let steps = dataset_steps(&dataset, &(poses.clone(), poses));
        let rows = replay_pass(
            &mut stream,
            "with verdicts",
            &dataset,
            &steps,
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
