//! `humem ingest`: a recording streamed into a running server as a robot
//! would stream it, and the loop candidates it got back, scored against
//! the recording's poses.
//!
//! Each keyframe is inserted with its image and pose, then asked about as
//! a loop query (its own map, the minimum frame gap, the server's own
//! operating point), which is what the ORB-SLAM3 plugin does. So what is
//! printed is what a robot driving this recording would have been told,
//! candidate by candidate, with whether each was a true place by the
//! paper's rule (within 5 m and 30°, at least the gap earlier). The
//! keyframes stay on the server under the robot and session named.

use anyhow::{bail, Context};
use humem_server::proto;

use super::dataset::Dataset;
use super::source::SourceArgs;
use super::truth::{self, Kind, PoseRule};

/// Options of `humem ingest`.
#[derive(Debug, Clone, clap::Args)]
pub struct IngestArgs {
    /// The recording, and how to read it.
    #[command(flatten)]
    pub recording: SourceArgs,
    /// The server, e.g. http://127.0.0.1:50051.
    #[arg(long, value_name = "URL")]
    pub server: String,
    /// TLS to that server (`--tls-ca`, `--tls-cert`, `--tls-key`).
    #[command(flatten)]
    pub tls: humem_server::client::ClientCredentials,
    /// The robot the keyframes are stored as.
    #[arg(long, default_value = "recording")]
    pub robot: String,
    /// The session they are stored in; default: the recording's name.
    #[arg(long)]
    pub session: Option<String>,
    /// Loop queries skip this many most recent keyframes (the paper's gap).
    #[arg(long, default_value_t = 100)]
    pub min_gap: usize,
    /// Ground truth: largest distance, metres.
    #[arg(long, default_value_t = 5.0)]
    pub max_distance: f64,
    /// Ground truth: largest orientation difference, degrees.
    #[arg(long, default_value_t = 30.0)]
    pub max_angle: f64,
    /// Candidates asked for per query (at most; the server's operating
    /// point decides how many it gives).
    #[arg(long, default_value_t = 3)]
    pub top_n: u32,
}

/// `humem ingest`.
pub async fn run(args: IngestArgs) -> anyhow::Result<()> {
    let Some(source) = args.recording.source.clone() else {
        bail!("--source names the recording to ingest");
    };
    let materialized = args.recording.materialize(&source)?;
    let rule = PoseRule {
        max_distance_m: args.max_distance,
        max_angle_deg: args.max_angle,
        min_frame_gap: args.min_gap,
    };
    let dataset = Dataset::open(&materialized.folder, &rule, Some(args.min_gap))?;
    if dataset.kind != Kind::Loop {
        bail!(
            "humem ingest streams one drive (a loop); {} is a pairs data set",
            source.display()
        );
    }
    let poses_file = materialized.folder.join("sequence_poses.txt");
    let poses: Vec<(f64, truth::Pose)> = if poses_file.is_file() {
        truth::load_tum(&poses_file)?
    } else {
        Vec::new()
    };
    let session = args.session.clone().unwrap_or_else(|| dataset.name.clone());
    let mut client = humem_server::client::connect(&args.server, &args.tls)
        .await
        .with_context(|| format!("connecting to {}", args.server))?;

    let bar = super::progress::progress(dataset.queries.len(), "ingest");
    let mut tally = Tally::default();
    for (i, image) in dataset.queries.iter().enumerate() {
        let data = std::fs::read(image).with_context(|| format!("reading {}", image.display()))?;
        let (timestamp, pose) = match poses.get(i) {
            Some((t, p)) => (*t, Some(proto_pose(p))),
            None => (i as f64, None),
        };
        client
            .insert(proto::InsertRequest {
                keyframe: Some(proto::Keyframe {
                    robot_id: args.robot.clone(),
                    session_id: session.clone(),
                    keyframe_id: Some(i as u64),
                    frame_id: Some(i as u64),
                    timestamp,
                    map_id: Some(0),
                    pose,
                    content: Some(proto::keyframe::Content::Image(proto::Image {
                        data,
                        ..Default::default()
                    })),
                }),
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .with_context(|| format!("inserting keyframe {i} ({})", image.display()))?;
        let reply = client
            .query(proto::QueryRequest {
                robot_id: args.robot.clone(),
                session_id: session.clone(),
                keyframe_id: Some(i as u64),
                scope: proto::Scope::SameMap as i32,
                min_frame_gap: Some(args.min_gap as u64),
                top_n: Some(args.top_n),
                ..Default::default()
            })
            .await
            .map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))
            .with_context(|| format!("querying keyframe {i}"))?
            .into_inner();
        let truth = dataset.matches.get(&i);
        tally.query(truth.is_some());
        let mut right_found = false;
        for candidate in &reply.candidates {
            let right = truth.is_some_and(|m| m.contains(&(candidate.keyframe_id as usize)));
            right_found |= right;
            tally.candidate(right);
            let line = format!(
                "keyframe {i:>6} -> {:>6}  score {:.3}  {}",
                candidate.keyframe_id,
                candidate.score,
                match (right, truth.is_some()) {
                    (true, _) => "true place",
                    (false, true) => "WRONG (a true place exists)",
                    (false, false) => "WRONG (no true place)",
                }
            );
            // A hidden bar (output not a terminal) prints nothing.
            if bar.is_hidden() {
                println!("{line}");
            } else {
                bar.println(line);
            }
        }
        tally.answered(!reply.candidates.is_empty(), right_found, truth.is_some());
        bar.inc(1);
    }
    bar.finish_and_clear();
    println!("{}", tally.table(&dataset.truth_source, !poses.is_empty()));
    println!(
        "{} keyframes stored as robot {:?}, session {:?} on {}; they stay in its store \
         (remove them with `humem reset-session --robot {} --session {} --server {}`)",
        dataset.queries.len(),
        args.robot,
        session,
        args.server,
        args.robot,
        session,
        args.server
    );
    Ok(())
}

fn proto_pose(p: &truth::Pose) -> proto::Pose {
    let q = p.r.quaternion();
    proto::Pose {
        translation: Some(proto::Vec3 {
            x: p.t.x,
            y: p.t.y,
            z: p.t.z,
        }),
        rotation: Some(proto::Quaternion {
            w: q.w,
            x: q.i,
            y: q.j,
            z: q.k,
        }),
    }
}

/// The counts behind the summary.
#[derive(Debug, Default, Clone, PartialEq)]
struct Tally {
    queries: usize,
    with_truth: usize,
    answered: usize,
    candidates: usize,
    right: usize,
    /// Queries with a true place whose candidates included one.
    found: usize,
    /// Answered queries without any true place.
    false_alarms: usize,
}

impl Tally {
    fn query(&mut self, has_truth: bool) {
        self.queries += 1;
        self.with_truth += usize::from(has_truth);
    }

    fn candidate(&mut self, right: bool) {
        self.candidates += 1;
        self.right += usize::from(right);
    }

    fn answered(&mut self, answered: bool, right_found: bool, has_truth: bool) {
        self.answered += usize::from(answered);
        self.found += usize::from(right_found);
        self.false_alarms += usize::from(answered && !has_truth);
    }

    fn table(&self, truth: &str, scored: bool) -> String {
        let ratio = |a: usize, b: usize| {
            if b == 0 {
                "-".to_string()
            } else {
                format!("{:.3} ({a}/{b})", a as f64 / b as f64)
            }
        };
        let mut out = format!(
            "| queries | answered | candidates | candidate precision | loops found | false alarms |\n\
             | --- | --- | --- | --- | --- | --- |\n\
             | {} | {} | {} | {} | {} | {} |",
            self.queries,
            self.answered,
            self.candidates,
            ratio(self.right, self.candidates),
            ratio(self.found, self.with_truth),
            ratio(self.false_alarms, self.queries - self.with_truth),
        );
        if !scored {
            out.push_str("\n(no poses: nothing to score the candidates against)");
        } else {
            out.push_str(&format!("\nground truth: {truth}"));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tally_counts_precision_loops_and_false_alarms() {
        let mut t = Tally::default();
        // A query with a true place, answered with one right and one wrong.
        t.query(true);
        t.candidate(true);
        t.candidate(false);
        t.answered(true, true, true);
        // A query without a true place, answered: a false alarm.
        t.query(false);
        t.candidate(false);
        t.answered(true, false, false);
        // A query with a true place, unanswered.
        t.query(true);
        t.answered(false, false, true);
        let table = t.table("poses", true);
        assert!(
            table.contains("| 3 | 2 | 3 | 0.333 (1/3) | 0.500 (1/2) | 1.000 (1/1) |"),
            "{table}"
        );
    }
}
