//! `humem load`: a load generator that drives a running server the way a
//! fleet does, and prints what it achieved.
//!
//! Each simulated robot is one SLAM client: at a fixed rate it inserts a
//! keyframe and asks a loop-closure query about it, without waiting for the
//! previous answers (as ORB-SLAM3's asynchronous client does), so the
//! server's latest-wins scheduling and ingest push-back are exercised for
//! real. The robots' ticks are spread over the period, as independent
//! robots' are (`--in-phase` sends a burst instead). Keyframes carry
//! images from a folder or synthetic features. The report gives the achieved rate, latency percentiles (HdrHistogram),
//! superseded queries and errors by gRPC code.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use humem_server::client::Connection;

use super::args::ServerArg;
use humem_core::synthetic::{place_descriptor, place_of, Rng};
use humem_server::proto;
use humem_server::proto::place_recognition_client::PlaceRecognitionClient;

/// Options of `humem load`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoadArgs {
    /// The server and how to reach it.
    #[command(flatten)]
    pub server: ServerArg,
    /// Simulated robots.
    #[arg(long, default_value_t = 8)]
    pub robots: usize,
    /// Keyframes (and queries) per second per robot.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// How long to run, in seconds.
    #[arg(long, default_value_t = 60.0)]
    pub duration: f64,
    /// Folder of JPEG/PNG images to send; default: synthetic features.
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// Descriptor length of the synthetic features.
    #[arg(long, default_value_t = 256)]
    pub dim: usize,
    /// How synthetic descriptors are made: `places` (each robot passes
    /// places in runs of 4 keyframes, a descriptor is its place's centre
    /// plus noise, as `humem bench scan` makes them) or `drift` (a sinusoid
    /// whose phase drifts and repeats every 200 keyframes: every descriptor
    /// lies in one plane and about one in 16 of a fleet's is an exact copy,
    /// a worst case for the compressed scan's bounds).
    #[arg(long, value_enum, default_value_t = Descriptors::Places)]
    pub descriptors: Descriptors,
    /// Queries carry the frame's content (as a relocalisation would) instead
    /// of naming the stored keyframe, so each one runs the models too.
    #[arg(long)]
    pub query_content: bool,
    /// Linux process id of the server, to report its peak memory (VmHWM).
    #[arg(long)]
    pub server_pid: Option<u32>,
    /// The queries each keyframe asks, one per scope, as ORB-SLAM3 asks a
    /// loop query over its own map and a merge query over every other:
    /// `same-map,other-maps`. Default: one query over every map.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [LoadScope::AllMaps])]
    pub scopes: Vec<LoadScope>,
    /// Every this many ticks, each robot asks its `other-maps` (or, without
    /// one, its first) query again with `exact` set and compares the top
    /// candidates: how often the answer equals an exact pass's (0: never).
    /// The robots take turns, so the exact passes are spread over time.
    #[arg(long, default_value_t = 0)]
    pub exact_every: u64,
    /// Keyframe id of each robot's first keyframe. A run that continues a
    /// store an earlier run filled starts after that run's last id, so its
    /// keyframes are appended to the robots' maps as a SLAM system's are;
    /// ids from 0 replace the stored keyframes instead.
    #[arg(long, default_value_t = 0)]
    pub first_keyframe_id: u64,
    /// Every robot ticks at the same instant, so the server meets a burst
    /// of `robots` keyframes at once every period (a worst case). Without
    /// it the robots' ticks are spread evenly over the period, as the
    /// keyframes of independent robots arrive.
    #[arg(long)]
    pub in_phase: bool,
}

/// A query scope of `humem load --scopes`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LoadScope {
    /// The querying keyframe's own map (loop closure).
    SameMap,
    /// Every map but its own (map merging).
    OtherMaps,
    /// Every map (relocalisation).
    AllMaps,
}

impl LoadScope {
    fn proto(self) -> proto::Scope {
        match self {
            LoadScope::SameMap => proto::Scope::SameMap,
            LoadScope::OtherMaps => proto::Scope::OtherMaps,
            LoadScope::AllMaps => proto::Scope::AllMaps,
        }
    }

    fn name(self) -> &'static str {
        match self {
            LoadScope::SameMap => "same-map",
            LoadScope::OtherMaps => "other-maps",
            LoadScope::AllMaps => "all-maps",
        }
    }
}

/// Outcomes of one kind of call.
struct Tally {
    latency: Histogram<u64>,
    ok: u64,
    superseded: u64,
    errors: BTreeMap<String, u64>,
    /// The first message seen for each error code, to tell causes apart.
    first_message: BTreeMap<String, String>,
}

impl Tally {
    fn new() -> Tally {
        Tally {
            latency: Histogram::new_with_bounds(1, 120_000_000, 3).expect("valid bounds"),
            ok: 0,
            superseded: 0,
            errors: BTreeMap::new(),
            first_message: BTreeMap::new(),
        }
    }

    fn record(&mut self, took: Duration, outcome: Result<bool, tonic::Status>) {
        let _ = self.latency.record(took.as_micros().max(1) as u64);
        match outcome {
            Ok(true) => self.ok += 1,
            Ok(false) => self.superseded += 1,
            Err(status) => {
                let code = format!("{:?}", status.code());
                self.first_message
                    .entry(code.clone())
                    .or_insert_with(|| status.message().to_string());
                *self.errors.entry(code).or_insert(0) += 1
            }
        }
    }
}

#[derive(Clone)]
struct Tallies {
    insert: Arc<Mutex<Tally>>,
    /// One per scope of `--scopes`, in its order.
    query: Arc<Vec<Mutex<Tally>>>,
    /// Sampled queries asked again exact.
    exact: Arc<Mutex<ExactCheck>>,
}

/// What the sampled queries asked again with `exact` set found.
#[derive(Debug, Default, Clone, Copy)]
struct ExactCheck {
    /// Queries compared.
    compared: u64,
    /// Of them, those whose top candidate is the exact pass's.
    same: u64,
    /// Those whose top candidate shows the exact top candidate's place
    /// (where the descriptors are `places`).
    same_place: u64,
}

/// How synthetic descriptors are made (`--descriptors`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Descriptors {
    /// Place centres plus noise, unit length.
    Places,
    /// A drifting sinusoid (the generator before `places`).
    Drift,
}

/// Distinct places of the `places` descriptors.
const PLACES: u64 = 5_000;

impl Descriptors {
    /// Robot `robot`'s descriptor at keyframe `tick`.
    fn make(self, dim: usize, robot: usize, tick: u64) -> Vec<f32> {
        match self {
            Descriptors::Drift => {
                // A slowly drifting descriptor: a robot revisits what it saw.
                let phase = (tick % 200) as f32 * 0.03 + robot as f32;
                (0..dim).map(|i| (phase + i as f32 * 0.37).sin()).collect()
            }
            Descriptors::Places => {
                let mut noise = Rng::new((robot as u64) << 40 ^ tick ^ 0x5eed);
                place_descriptor(dim, place_of(PLACES, robot as u64, tick), &mut noise)
            }
        }
    }
}

/// The place of the `places` descriptors that keyframe `id` of a robot
/// of this load (`load-robot-N`) shows; None for another robot.
fn load_place(robot_id: &str, id: u64) -> Option<u64> {
    let robot: u64 = robot_id.strip_prefix("load-robot-")?.parse().ok()?;
    Some(place_of(PLACES, robot, id))
}

/// What a robot sends at each tick.
enum Content {
    Images(Arc<Vec<Vec<u8>>>),
    Synthetic(usize, Descriptors),
}

impl Content {
    /// Where robot `robot` is at keyframe `tick`: where what it sees is, so
    /// that a revisit stands where the map put the first visit (as a
    /// SLAM map's poses have it, and as the drift envelope expects). The
    /// images are passed in turn around a loop of one metre per image;
    /// the `places` descriptors' places stand 10 m apart along x; the
    /// drifting sinusoid repeats around a loop of 200 m.
    fn position(&self, robot: usize, tick: u64) -> [f64; 3] {
        let around = |step: u64, len: u64| {
            let radius = len as f64 / std::f64::consts::TAU;
            let angle = std::f64::consts::TAU * (step % len) as f64 / len as f64;
            [radius * angle.cos(), radius * angle.sin(), 0.0]
        };
        match self {
            Content::Images(images) => {
                around(robot as u64 * 7919 + tick, images.len().max(1) as u64)
            }
            Content::Synthetic(_, Descriptors::Places) => {
                let place = place_of(PLACES, robot as u64, tick);
                [10.0 * place as f64 + 0.5 * (tick % 4) as f64, 0.0, 0.0]
            }
            Content::Synthetic(_, Descriptors::Drift) => around(tick, 200),
        }
    }

    fn keyframe_content(&self, robot: usize, tick: u64) -> proto::keyframe::Content {
        match self {
            Content::Images(images) => {
                let i = (robot * 7919 + tick as usize) % images.len();
                proto::keyframe::Content::Image(proto::Image {
                    data: images[i].clone(),
                    ..Default::default()
                })
            }
            Content::Synthetic(dim, descriptors) => {
                proto::keyframe::Content::Features(proto::Features {
                    global_descriptor: descriptors.make(*dim, robot, tick),
                    ..Default::default()
                })
            }
        }
    }
}

/// A simulated robot's keyframe `tick`: frame `3 tick`, map 0, its camera
/// at `position`.
pub(crate) fn keyframe(
    robot_id: &str,
    session_id: &str,
    tick: u64,
    timestamp: f64,
    position: [f64; 3],
    content: proto::keyframe::Content,
) -> proto::Keyframe {
    proto::Keyframe {
        robot_id: robot_id.into(),
        session_id: session_id.into(),
        keyframe_id: Some(tick),
        frame_id: Some(tick * 3),
        timestamp,
        map_id: Some(0),
        pose: Some(proto::Pose {
            translation: Some(proto::Vec3 {
                x: position[0],
                y: position[1],
                z: position[2],
            }),
            rotation: Some(proto::Quaternion {
                w: 1.0,
                ..Default::default()
            }),
        }),
        content: Some(content),
    }
}

fn load_images(dir: &std::path::Path) -> anyhow::Result<Vec<Vec<u8>>> {
    humem_perception::image::image_files(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .iter()
        .map(|p| std::fs::read(p).with_context(|| format!("reading {}", p.display())))
        .collect()
}

async fn robot(
    client: PlaceRecognitionClient<Connection>,
    robot: usize,
    args: Arc<LoadArgs>,
    content: Arc<Content>,
    tallies: Tallies,
) {
    let period = Duration::from_secs_f64(1.0 / args.rate.max(0.001));
    let mut ticker = tokio::time::interval_at(
        tokio::time::Instant::now() + first_tick_offset(&args, robot, period),
        period,
    );
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let end = Instant::now() + Duration::from_secs_f64(args.duration);
    let robot_id = format!("load-robot-{robot}");
    let mut calls = Vec::new();
    let mut tick = args.first_keyframe_id;
    while Instant::now() < end {
        ticker.tick().await;
        let keyframe = keyframe(
            &robot_id,
            "load",
            tick,
            tick as f64 * period.as_secs_f64(),
            content.position(robot, tick),
            content.keyframe_content(robot, tick),
        );
        let query_content =
            args.query_content
                .then(|| match content.keyframe_content(robot, tick) {
                    proto::keyframe::Content::Image(i) => proto::query_request::Content::Image(i),
                    proto::keyframe::Content::Features(f) => {
                        proto::query_request::Content::Features(f)
                    }
                });
        let (mut inserter, mut querier) = (client.clone(), client.clone());
        let tallies = tallies.clone();
        let robot_id = robot_id.clone();
        let scopes = args.scopes.clone();
        let exact_every = args.exact_every;
        // Insert, then ask about the new keyframe; the next tick does not
        // wait for either.
        calls.push(tokio::spawn(async move {
            let started = Instant::now();
            let inserted = inserter
                .insert(proto::InsertRequest {
                    keyframe: Some(keyframe),
                })
                .await
                .map(|_| true);
            let ok = inserted.is_ok();
            tallies
                .insert
                .lock()
                .unwrap()
                .record(started.elapsed(), inserted);
            if !ok {
                return;
            }
            let kind = if query_content.is_some() {
                proto::QueryKind::Relocalisation
            } else {
                proto::QueryKind::LoopClosure
            };
            let request = |scope: LoadScope, exact: bool| proto::QueryRequest {
                robot_id: robot_id.clone(),
                session_id: "load".into(),
                keyframe_id: Some(tick),
                frame_id: Some(tick * 3),
                content: query_content.clone(),
                kind: kind as i32,
                scope: scope.proto() as i32,
                // Compared answers must not depend on the operating point.
                threshold: (exact_every > 0).then_some(0.0),
                exact,
                ..Default::default()
            };
            let turn = tick + robot as u64;
            let checked = (exact_every > 0 && turn.is_multiple_of(exact_every)).then(|| {
                scopes
                    .iter()
                    .position(|&s| s == LoadScope::OtherMaps)
                    .unwrap_or(0)
            });
            for (i, &scope) in scopes.iter().enumerate() {
                let started = Instant::now();
                let answer = querier.query(request(scope, false)).await;
                let took = started.elapsed();
                let top = |r: &proto::QueryResponse| {
                    r.candidates
                        .first()
                        .map(|c| (c.robot_id.clone(), c.session_id.clone(), c.keyframe_id))
                };
                let answered =
                    |r: &proto::QueryResponse| r.status() == proto::QueryStatus::Answered;
                // Only answered queries are compared (not one superseded).
                let approximate = answer
                    .as_ref()
                    .ok()
                    .filter(|r| answered(r.get_ref()))
                    .map(|r| top(r.get_ref()));
                tallies.query[i].lock().unwrap().record(
                    took,
                    answer.map(|r| r.into_inner().status() == proto::QueryStatus::Answered),
                );
                if checked == Some(i) {
                    let exact = match approximate {
                        Some(_) => querier.query(request(scope, true)).await.ok(),
                        None => None,
                    };
                    if let (Some(approximate), Some(exact)) =
                        (approximate, exact.filter(|r| answered(r.get_ref())))
                    {
                        let exact = top(exact.get_ref());
                        let place = |top: &Option<(String, String, u64)>| {
                            top.as_ref()
                                .and_then(|(robot, _, id)| load_place(robot, *id))
                        };
                        let mut check = tallies.exact.lock().unwrap();
                        check.compared += 1;
                        check.same += u64::from(approximate == exact);
                        check.same_place += u64::from(
                            place(&approximate).is_some_and(|p| Some(p) == place(&exact)),
                        );
                    }
                }
            }
        }));
        tick += 1;
    }
    for call in calls {
        let _ = call.await;
    }
}

/// How long after the start robot `robot` ticks first: 0 for every robot
/// with `--in-phase`, else its share of the period.
fn first_tick_offset(args: &LoadArgs, robot: usize, period: Duration) -> Duration {
    if args.in_phase {
        return Duration::ZERO;
    }
    period.mul_f64(robot as f64 / args.robots.max(1) as f64)
}

fn peak_memory_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// Runs the load and prints the report.
pub async fn run(args: LoadArgs) -> anyhow::Result<()> {
    let content = Arc::new(match &args.images {
        Some(dir) => Content::Images(Arc::new(load_images(dir)?)),
        None => Content::Synthetic(args.dim.max(1), args.descriptors),
    });
    let channel = humem_server::client::channel(&args.server.server, &args.server.tls).await?;
    let client = PlaceRecognitionClient::new(channel).max_encoding_message_size(64 << 20);
    anyhow::ensure!(!args.scopes.is_empty(), "--scopes names no scope");
    let tallies = Tallies {
        insert: Arc::new(Mutex::new(Tally::new())),
        query: Arc::new(
            args.scopes
                .iter()
                .map(|_| Mutex::new(Tally::new()))
                .collect(),
        ),
        exact: Arc::new(Mutex::new(ExactCheck::default())),
    };
    let args = Arc::new(args);
    println!(
        "humem load: {} robots x {} Hz{} for {} s against {} ({})",
        args.robots,
        args.rate,
        if args.in_phase { " in phase" } else { "" },
        args.duration,
        args.server.server,
        match (&args.images, args.descriptors) {
            (Some(_), _) => "images".to_string(),
            (None, d) => format!(
                "synthetic {}-d features, {}",
                args.dim,
                if d == Descriptors::Places {
                    "places"
                } else {
                    "drift"
                }
            ),
        }
    );
    let started = Instant::now();
    let robots: Vec<_> = (0..args.robots)
        .map(|r| {
            tokio::spawn(robot(
                client.clone(),
                r,
                args.clone(),
                content.clone(),
                tallies.clone(),
            ))
        })
        .collect();
    for r in robots {
        r.await?;
    }
    let wall = started.elapsed().as_secs_f64();

    println!(
        "\n{:<16} {:>7} {:>7} {:>10} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "call",
        "sent",
        "ok",
        "superseded",
        "errors",
        "ok/s",
        "p50 ms",
        "p95 ms",
        "p99 ms",
        "max ms"
    );
    let query_names: Vec<String> = args
        .scopes
        .iter()
        .map(|s| format!("query/{}", s.name()))
        .collect();
    let calls = std::iter::once(("insert", &*tallies.insert)).chain(
        query_names
            .iter()
            .map(String::as_str)
            .zip(tallies.query.iter()),
    );
    for (name, tally) in calls {
        let t = tally.lock().unwrap();
        let errors: u64 = t.errors.values().sum();
        let ms = |q: f64| t.latency.value_at_quantile(q) as f64 / 1000.0;
        println!(
            "{name:<16} {:>7} {:>7} {:>10} {:>7} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
            t.ok + t.superseded + errors,
            t.ok,
            t.superseded,
            errors,
            t.ok as f64 / wall,
            ms(0.5),
            ms(0.95),
            ms(0.99),
            t.latency.max() as f64 / 1000.0
        );
        for (code, n) in &t.errors {
            let message = t.first_message.get(code).map_or("", String::as_str);
            println!("{:<16} error {code}: {n} (first: {message:?})", "");
        }
    }
    let ExactCheck {
        compared,
        same,
        same_place,
    } = *tallies.exact.lock().unwrap();
    if compared > 0 {
        println!(
            "\nexact check: {same} of {compared} sampled queries ({:.1} %) have the exact pass's top candidate",
            100.0 * same as f64 / compared as f64
        );
        if args.images.is_none() && args.descriptors == Descriptors::Places {
            println!(
                "             {same_place} of {compared} ({:.1} %) have a top candidate at the exact top candidate's place",
                100.0 * same_place as f64 / compared as f64
            );
        }
    }
    if let Some(pid) = args.server_pid {
        match peak_memory_kib(pid) {
            Some(kib) => println!(
                "\nserver peak memory (VmHWM): {:.1} MiB",
                kib as f64 / 1024.0
            ),
            None => println!("\nserver peak memory: /proc/{pid}/status not readable"),
        }
    }
    Ok(())
}
