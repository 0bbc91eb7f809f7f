//! `humem eval --server ADDR`: the same protocol, measured through a running
//! service over gRPC, so what is measured is the service itself (transport,
//! validation, queues, perception, store and ranking).
//!
//! The evaluation plays a SLAM client. Every keyframe is inserted with its
//! image, and each selected query then asks about its stored keyframe, once
//! per layer configuration, so the models run once per image whatever the
//! number of configurations. Robot ids are unique to the run, queries are
//! scoped to the reference robot, and the run's sessions are reset at the
//! end, so a shared server is left as it was.
//!
//! - `loop`: frames go in order into one session and a frame is asked about
//!   right after it is stored, with the data set's minimum frame gap: the
//!   server holds only earlier frames, as in a real drive.
//! - `pairs`: the references go in first; then, per condition, a query
//!   session stores each selected query frame and its two predecessors (its
//!   temporal context) and asks about it.
//!
//! A query's latency is the insert (without the server's decoding) plus the
//! query call, both timed at this client.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use humem_server::client::Connection;

use super::dataset::Dataset;
use super::degrade::Degradation;
use super::images::image_bytes;
use super::precision::OperatingPoint;
use super::progress::progress;
use super::protocol::{Samples, Selection};
use super::replay_rows::ReplayRow;
use super::truth::Kind;
use super::verdict_replay::{self, Asked, Ranked, ReplayOptions};
use humem_core::vpr::params::Layers;
use humem_server::proto;
use humem_server::proto::place_recognition_client::PlaceRecognitionClient;

/// The run's place on the server.
pub struct Remote {
    client: PlaceRecognitionClient<Connection>,
    reference_robot: String,
    query_robot: String,
    session: String,
    /// Query sessions opened so far, reset at the end.
    sessions: Vec<(String, String)>,
    top_n: u32,
}

fn layers_proto(layers: Layers) -> proto::Layers {
    match layers {
        l if l == Layers::SCAL => proto::Layers::Scal,
        l if l == Layers::SCAL_OSRL => proto::Layers::ScalOsrl,
        l if l == Layers::SCAL_OGTL => proto::Layers::ScalOgtl,
        l if l == Layers::FULL_SUPPORT_ONLY => proto::Layers::FullSupportOnly,
        _ => proto::Layers::Full,
    }
}

fn keyframe(robot: &str, session: &str, index: usize, image: Vec<u8>) -> proto::Keyframe {
    proto::Keyframe {
        robot_id: robot.to_string(),
        session_id: session.to_string(),
        keyframe_id: Some(index as u64),
        frame_id: Some(index as u64),
        timestamp: index as f64,
        map_id: Some(0),
        pose: Some(proto::Pose {
            translation: Some(proto::Vec3::default()),
            rotation: Some(proto::Quaternion {
                w: 1.0,
                ..Default::default()
            }),
        }),
        content: Some(proto::keyframe::Content::Image(proto::Image {
            data: image,
            ..Default::default()
        })),
    }
}

fn seconds(timings: &[proto::StageTiming], stage: &str) -> f64 {
    timings
        .iter()
        .filter(|t| t.stage == stage)
        .map(|t| t.seconds)
        .sum()
}

impl Remote {
    /// Connects and names the run's robots and session.
    pub async fn connect(
        url: &str,
        tls: &humem_server::client::ClientCredentials,
        dataset: &Dataset,
        top_n: usize,
    ) -> anyhow::Result<Remote> {
        let client = humem_server::client::connect(url, tls).await?;
        let run = format!(
            "{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs())
        );
        Ok(Remote {
            client,
            reference_robot: format!("eval-{run}-{}-ref", dataset.name),
            query_robot: format!("eval-{run}-{}-query", dataset.name),
            session: "eval".into(),
            sessions: Vec::new(),
            top_n: top_n.min(100) as u32,
        })
    }

    /// Inserts one keyframe; returns the time without the server's decoding
    /// and the stage timings.
    async fn insert(
        &mut self,
        keyframe: proto::Keyframe,
    ) -> anyhow::Result<(Duration, Vec<proto::StageTiming>)> {
        let what = format!(
            "inserting keyframe {} of {}",
            keyframe.keyframe_id.unwrap_or_default(),
            keyframe.robot_id
        );
        let started = Instant::now();
        let reply = self
            .client
            .insert(proto::InsertRequest {
                keyframe: Some(keyframe),
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .context(what)?
            .into_inner();
        let took = started
            .elapsed()
            .saturating_sub(Duration::from_secs_f64(seconds(&reply.timings, "decode")));
        Ok((took, reply.timings))
    }

    /// Asks about a stored keyframe with one layer configuration.
    async fn query(
        &mut self,
        robot: &str,
        session: &str,
        index: usize,
        min_frame_gap: u64,
        layers: Layers,
    ) -> anyhow::Result<(Duration, proto::QueryResponse)> {
        let started = Instant::now();
        let reply = self
            .client
            .query(proto::QueryRequest {
                robot_id: robot.to_string(),
                session_id: session.to_string(),
                keyframe_id: Some(index as u64),
                scope: proto::Scope::Listed as i32,
                robot_ids: vec![self.reference_robot.clone()],
                min_frame_gap: Some(min_frame_gap),
                top_n: Some(self.top_n),
                threshold: Some(0.0),
                layers: layers_proto(layers) as i32,
                ..Default::default()
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .with_context(|| format!("querying keyframe {index} of {robot}"))?
            .into_inner();
        if reply.status() != proto::QueryStatus::Answered {
            bail!(
                "query of keyframe {index} was not answered: {:?}",
                reply.status()
            );
        }
        Ok((started.elapsed(), reply))
    }

    /// Stores every reference of a `pairs` data set.
    pub async fn insert_references(&mut self, dataset: &Dataset) -> anyhow::Result<()> {
        if dataset.kind == Kind::Loop {
            return Ok(()); // a loop's references are its frames, stored as they come
        }
        let bar = progress(dataset.references.len(), "references (server)");
        let (robot, session) = (self.reference_robot.clone(), self.session.clone());
        self.sessions.push((robot.clone(), session.clone()));
        for (i, path) in dataset.references.iter().enumerate() {
            let image = image_bytes(path, None)?;
            self.insert(keyframe(&robot, &session, i, image)).await?;
            bar.inc(1);
        }
        bar.finish_and_clear();
        Ok(())
    }

    /// Runs one condition: every method's answers, latencies and stages.
    pub async fn condition(
        &mut self,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        methods: &[(&'static str, Layers)],
        selection: &Selection,
    ) -> anyhow::Result<Vec<Samples>> {
        let selected = selection.all();
        let condition = super::degrade::condition_name(degradation);
        let (robot, session, gap, frames): (String, String, u64, Vec<usize>) = match dataset.kind {
            Kind::Loop => {
                if degradation.is_some() {
                    bail!(
                        "--degrade on a loop data set is measured in-process only: over --server \
                         the degraded revisits would need clean references newer than the gap"
                    );
                }
                let last = selected.iter().max().copied().unwrap_or(0);
                (
                    self.reference_robot.clone(),
                    self.session.clone(),
                    dataset.min_frame_gap as u64,
                    (0..=last).collect(),
                )
            }
            Kind::Pairs => {
                // Each selected query and its two predecessors, in order.
                let frames: BTreeSet<usize> = selected
                    .iter()
                    .flat_map(|&q| (0..3).filter_map(move |j| q.checked_sub(j)))
                    .collect();
                (
                    self.query_robot.clone(),
                    format!("{}-{condition}", self.session),
                    0,
                    frames.into_iter().collect(),
                )
            }
        };
        self.sessions.push((robot.clone(), session.clone()));
        let mut samples: Vec<Samples> = methods.iter().map(|_| Samples::default()).collect();
        let asked: BTreeSet<usize> = selected.iter().copied().collect();
        let bar = progress(frames.len(), &format!("{condition} (server)"));
        for index in frames {
            let image = image_bytes(&dataset.queries[index], degradation)?;
            let (insert_took, insert_stages) = self
                .insert(keyframe(&robot, &session, index, image))
                .await?;
            bar.inc(1);
            if !asked.contains(&index) {
                continue;
            }
            for (m, &(_, layers)) in methods.iter().enumerate() {
                let (took, reply) = self.query(&robot, &session, index, gap, layers).await?;
                let top: Vec<(usize, f32)> = reply
                    .candidates
                    .iter()
                    .map(|c| (c.keyframe_id as usize, c.score))
                    .collect();
                samples[m].record(&top, dataset.matches.get(&index));
                if selection.is_timed(index) {
                    samples[m].latencies.push(insert_took + took);
                    for t in insert_stages.iter().chain(reply.timings.iter()) {
                        if t.stage != "decode" {
                            *samples[m].stage_ms.entry(t.stage.clone()).or_default() +=
                                t.seconds * 1e3;
                        }
                    }
                }
            }
        }
        bar.finish_and_clear();
        Ok(samples)
    }

    /// Removes everything the run stored.
    pub async fn clean_up(&mut self) -> anyhow::Result<u64> {
        let mut erased = 0;
        for (robot_id, session_id) in std::mem::take(&mut self.sessions) {
            erased += self
                .client
                .reset_session(proto::ResetSessionRequest {
                    robot_id,
                    session_id,
                })
                .await
                .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
                .context("resetting the evaluation's sessions")?
                .into_inner()
                .erased;
        }
        Ok(erased)
    }

    /// `--replay-verdicts` through the service: the data set streamed once
    /// without reporting verdicts and once reporting them with
    /// `ReportVerification`, each pass under robots of its own (removed at
    /// the end with the rest of the run).
    pub async fn replay_verdicts(
        &mut self,
        params: &humem_core::vpr::params::VprParams,
        dir: &std::path::Path,
        dataset: &Dataset,
        options: ReplayOptions,
    ) -> anyhow::Result<Vec<ReplayRow>> {
        let point = OperatingPoint {
            threshold: params.threshold(),
            max_candidates: params.max_candidates,
        };
        let (poses, own_poses) = verdict_replay::replay_poses(dir, dataset, &options)?;
        if !own_poses {
            tracing::warn!(
                "{} has no poses: the replay stands its frames along a line, and a server's drift envelope lowers every revisit on it; replay it against a server run with vpr.max_drift_ratio = 1",
                dataset.name
            );
        }
        let steps = verdict_replay::dataset_steps(dataset, &poses);
        let mut rows = Vec::new();
        for (n, (pass, report)) in [("without verdicts", false), ("with verdicts", true)]
            .into_iter()
            .enumerate()
        {
            let prefix = format!("{}-replay{n}", self.query_robot);
            for robot in [verdict_replay::ROBOT, verdict_replay::REFERENCE_ROBOT] {
                self.sessions
                    .push((format!("{prefix}-{robot}"), self.session.clone()));
            }
            let mut stream = RemoteStream {
                remote: self,
                prefix,
                dataset,
            };
            rows.extend(
                verdict_replay::replay_pass(
                    &mut stream,
                    pass,
                    dataset,
                    &steps,
                    point,
                    options,
                    report,
                )
                .await?,
            );
        }
        Ok(rows)
    }
}

/// A replay pass through the service: robots named `prefix-drive` and
/// `prefix-reference`, frames inserted with their images and poses.
struct RemoteStream<'a> {
    remote: &'a mut Remote,
    prefix: String,
    dataset: &'a Dataset,
}

impl RemoteStream<'_> {
    fn robot(&self, robot: &str) -> String {
        format!("{}-{robot}", self.prefix)
    }
}

impl verdict_replay::ReplayStream for RemoteStream<'_> {
    /// Stores the image as keyframe `id`; its frame id and timestamp stay
    /// the image's index, as in the rest of the run.
    async fn store(
        &mut self,
        robot: &str,
        id: u64,
        image: usize,
        map: u64,
        pose: humem_core::keyframe::Pose,
    ) -> anyhow::Result<()> {
        let path = if robot == verdict_replay::REFERENCE_ROBOT {
            &self.dataset.references[image]
        } else {
            &self.dataset.queries[image]
        };
        let mut kf = keyframe(
            &self.robot(robot),
            &self.remote.session,
            image,
            image_bytes(path, None)?,
        );
        kf.keyframe_id = Some(id);
        kf.map_id = Some(map);
        kf.pose = Some(humem_server::api::convert::pose(&pose));
        self.remote.insert(kf).await?;
        Ok(())
    }

    async fn move_to(
        &mut self,
        id: u64,
        _: u64,
        _: humem_core::keyframe::Pose,
    ) -> anyhow::Result<()> {
        bail!("moving keyframe {id}: a replay over a running service streams the data set's own poses, which never move")
    }

    async fn erase(&mut self, id: u64) -> anyhow::Result<()> {
        bail!("erasing keyframe {id}: a replay over a running service streams the data set's own keyframes, which are never erased")
    }

    async fn ask(&mut self, q: u64, pairs: bool, gap: usize) -> anyhow::Result<Asked> {
        let (scope, robot_ids) = if pairs {
            (
                proto::Scope::Listed,
                vec![self.robot(verdict_replay::REFERENCE_ROBOT)],
            )
        } else {
            (proto::Scope::SameMap, Vec::new())
        };
        let robot = self.robot(verdict_replay::ROBOT);
        let reply = self
            .remote
            .client
            .query(proto::QueryRequest {
                robot_id: robot.clone(),
                session_id: self.remote.session.clone(),
                keyframe_id: Some(q),
                scope: scope as i32,
                robot_ids,
                min_frame_gap: Some(gap as u64),
                top_n: Some(self.remote.top_n),
                threshold: Some(0.0),
                layers: proto::Layers::Full as i32,
                ..Default::default()
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .with_context(|| format!("querying keyframe {q} of {robot}"))?
            .into_inner();
        if reply.status() != proto::QueryStatus::Answered {
            bail!(
                "query of keyframe {q} was not answered: {:?}",
                reply.status()
            );
        }
        Ok(Asked {
            ranked: reply
                .candidates
                .iter()
                .map(|c| Ranked {
                    id: c.keyframe_id,
                    score: c.score,
                    drift_ratio: c
                        .evidence
                        .as_ref()
                        .and_then(|e| e.drift.as_ref())
                        .map(|d| d.ratio),
                })
                .collect(),
            threshold: reply.operating_threshold,
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
        let session = self.remote.session.clone();
        self.remote
            .client
            .report_verification(proto::ReportVerificationRequest {
                robot_id: self.robot(verdict_replay::ROBOT),
                session_id: session.clone(),
                keyframe_id: Some(q),
                candidate: Some(proto::KeyframeRef {
                    robot_id: self.robot(robot),
                    session_id: session,
                    keyframe_id: Some(candidate),
                }),
                kind: proto::VerificationKind::Loop as i32,
                outcome: if accepted {
                    proto::VerificationOutcome::Accepted
                } else {
                    proto::VerificationOutcome::Rejected
                } as i32,
                score: Some(score),
                ..Default::default()
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .with_context(|| format!("reporting the verdict on {candidate} for query {q}"))?;
        Ok(())
    }
}
