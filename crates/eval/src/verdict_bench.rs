//! `humem bench verdicts`: what SLAM's stored verdicts add to a query's
//! cost as they pile up, against the same query with verdicts off in the
//! same run.
//!
//! The worst case for the verdict lookup is one long session: every
//! verdict names a keyframe of the querying session, so every one is
//! placed and tested against the query's candidates
//! ([`humem_server::pipeline::query::apply_verdicts`]). The store is one
//! robot driving laps of one route (keyframe `i` at `i mod lap` metres, its
//! descriptor that place's centre plus noise, so that each lap revisits
//! the last), and the verdicts are what a SLAM system would report on it:
//! for a random keyframe of a later lap, its place on an earlier lap
//! (accepted, or rejected with the miss rate) or a random other place
//! (rejected). Each verdict count is timed on the same index, the verdicts
//! added incrementally; the estimate of the store's operating point
//! ([`humem_core::index::Index::operating_point`], recomputed when the
//! verdicts change and once a minute) is timed on its own.

use anyhow::ensure;

use humem_core::index::{Index, OPERATING_POINT_REFRESH_S};
use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::synthetic::{place_descriptor, Rng};
use humem_core::verdict::{unix_now, Verdict, VerificationKind};
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::params::{Layers, VprParams};
use humem_server::config::Config;
use humem_server::pipeline::query;
use humem_server::pipeline::request::{QueryKind, QuerySpec};

use super::scan_bench::{median_ms, timed};

/// Options of `humem bench verdicts`.
#[derive(Debug, Clone, clap::Args)]
pub struct VerdictBench {
    /// Keyframes of the one session.
    #[arg(long, default_value_t = 20_000)]
    pub keyframes: usize,
    /// Keyframes per lap of the route.
    #[arg(long, default_value_t = 2_000)]
    pub lap: usize,
    /// Verdict counts to time, ascending.
    #[arg(long, value_delimiter = ',', default_values_t = [0, 1_000, 10_000, 100_000])]
    pub verdicts: Vec<usize>,
    /// Timed queries per verdict count and setting.
    #[arg(long, default_value_t = 20)]
    pub queries: usize,
    /// Descriptor length.
    #[arg(long, default_value_t = 256)]
    pub dim: usize,
}

const ROBOT: &str = "robot";
const SESSION: &str = "session";

fn key(id: u64) -> KeyframeKey {
    SessionKey {
        robot_id: ROBOT.into(),
        session_id: SESSION.into(),
    }
    .keyframe(id)
}

/// Keyframe `i` of the drive.
fn keyframe(i: usize, lap: usize, dim: usize, noise: &mut Rng) -> SemanticKeyframe {
    let along = (i % lap) as u64;
    SemanticKeyframe {
        key: key(i as u64),
        frame_id: 3 * i as u64,
        timestamp: i as f64 * 0.2,
        map_id: 0,
        pose: Pose {
            translation: [along as f64, 0.0, 0.0],
            ..Pose::default()
        },
        features: Features {
            descriptor: place_descriptor(dim, along / 4, noise),
            scene: Vec::new(),
            objects: Vec::new(),
            appearance: Vec::new(),
        },
    }
}

/// A loop query for stored keyframe `id`, at the store's operating point.
fn spec(id: u64, top_n: usize) -> QuerySpec {
    QuerySpec {
        session: SessionKey {
            robot_id: ROBOT.into(),
            session_id: SESSION.into(),
        },
        map_id: None,
        frame_id: None,
        keyframe_id: Some(id),
        observation: None,
        predecessor_ids: Vec::new(),
        scope: Scope::SameMap,
        readable_robots: None,
        min_frame_gap: 90,
        top_n,
        threshold: None,
        layers: Layers::FULL,
        kind: QueryKind::LoopClosure,
        exact: false,
    }
}

/// One verdict a SLAM system would report on this drive.
fn verdict(rng: &mut Rng, keyframes: usize, lap: usize) -> Verdict {
    let q = lap + (rng.next() as usize) % (keyframes - lap);
    let true_place = !rng.next().is_multiple_of(4);
    let candidate = if true_place {
        q - lap * (1 + (rng.next() as usize) % (q / lap))
    } else {
        (rng.next() as usize) % (q - 90)
    };
    Verdict {
        query: key(q as u64),
        candidate: key(candidate as u64),
        kind: VerificationKind::Loop,
        accepted: true_place && !rng.next().is_multiple_of(10),
        relative: None,
        score: Some(0.36 + (rng.next() % 64) as f32 / 100.0),
        inliers: 0,
        reported_at: unix_now(),
    }
}

/// Runs the benchmark and prints the table.
pub fn verdicts(config: Config, args: VerdictBench) -> anyhow::Result<()> {
    ensure!(args.queries > 0, "--queries must be at least 1");
    ensure!(
        args.lap >= 200 && args.keyframes >= 2 * args.lap,
        "--keyframes must cover two laps of at least 200 keyframes"
    );
    ensure!(
        args.verdicts.windows(2).all(|w| w[0] <= w[1]),
        "--verdicts must be ascending"
    );
    let on: VprParams = config.vpr.clone();
    let mut off = on.clone();
    off.verdicts.enabled = false;
    eprintln!(
        "bench verdicts: one session of {} keyframes x {}",
        args.keyframes, args.dim
    );
    let mut noise = Rng::new(5);
    let mut index = Index::new(args.dim);
    for i in 0..args.keyframes {
        index.upsert(keyframe(i, args.lap, args.dim, &mut noise));
    }
    let mut rng = Rng::new(17);
    let ids: Vec<u64> = (0..args.queries + 2)
        .map(|_| (args.lap + (rng.next() as usize) % (args.keyframes - args.lap)) as u64)
        .collect();
    let top_n = config.vpr.max_candidates;
    let mut rows = Vec::new();
    let mut verdict_rng = Rng::new(23);
    for &count in &args.verdicts {
        while index.verdicts().len() < count {
            index.record_verdict(verdict(&mut verdict_rng, args.keyframes, args.lap));
        }
        let (mut without, mut with) = (Vec::new(), Vec::new());
        let mut candidates = 0usize;
        // The first two queries warm caches and are not timed.
        for (n, &id) in ids.iter().enumerate() {
            let spec = spec(id, top_n);
            let (t_off, a) = timed(|| query::run(&index, &off, &spec));
            let (t_on, b) = timed(|| query::run(&index, &on, &spec));
            let (a, b) = (
                a.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
                b.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
            );
            std::hint::black_box((&a, &b));
            candidates += b.candidates.len();
            if n >= 2 {
                without.push(t_off);
                with.push(t_on);
            }
        }
        // The operating point's estimate, as when the verdicts change.
        let later = unix_now() + 2.0 * OPERATING_POINT_REFRESH_S;
        let (estimate, point) = timed(|| index.operating_point(&on, later));
        let (without, with) = (median_ms(&without), median_ms(&with));
        rows.push(format!(
            "| {} | {without:.2} | {with:.2} | {:.2} | {:.2} | {:.2} | {:.1} |",
            index.verdicts().len(),
            with / without,
            estimate.as_secs_f64() * 1e3,
            point.threshold,
            candidates as f64 / ids.len() as f64,
        ));
    }
    println!(
        "\none session of {} keyframes x {} (laps of {}), {} timed queries each (median; SAME_MAP, all layers)\n",
        args.keyframes, args.dim, args.lap, args.queries
    );
    println!("| verdicts stored | query, verdicts off (ms) | query, verdicts on (ms) | on / off | operating point estimate (ms) | operating threshold | candidates per query |");
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    for row in rows {
        println!("{row}");
    }
    Ok(())
}
