//! `humem eval`: recall and latency on a data set, the paper's way.
//!
//! Everything runs in this process through the same code the service runs:
//! the perception models make features of every image, the references and
//! the query frames go into a real in-memory index as a SLAM client would
//! store them, and each selected query is answered by the service's own
//! query path (`humem_server::pipeline::query::run`: eligibility, scope,
//! temporal context, HuMem-VPR ranking) with the layers of each
//! configuration (ablations are configurations, not code). The end-to-end
//! test `eval_through_the_service_ranks_as_the_library_does` checks that a
//! running service gives the same numbers. Queries are the eligible ones, at most
//! `--max-queries` at evenly spaced indices; queries without a valid match
//! (a loop's first pass, a query nothing matches) are chosen the same way
//! and scored for precision only, since that is where false alarms come
//! from. Precision is taken at the configured operating point (threshold
//! and `max_candidates` of `[vpr]`, see [`super::precision`]). Latency is
//! measured on 30 evenly spaced queries after 10 warm-ups: perception
//! without decoding, plus ranking; building the database is not counted.

use std::collections::BTreeMap;
use std::io::{Cursor, IsTerminal};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;

use super::annotations::{self, Catalog};
use super::dataset::Dataset;
use super::degrade::Degradation;
use super::metrics::{self, LatencyStats, Retrieval};
use super::precision::{self, OperatingPoint, Precision, ScoredQuery};
use super::truth::{Kind, PoseRule};
use humem_core::index::Index;
use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::vpr::{Layers, Scope};
use humem_perception::image::{decode as image_decode, luma, EncodedImage, Encoding};
use humem_perception::{ImageInput, Perception};
use humem_server::config::Config;
use humem_server::pipeline::query;
use humem_server::pipeline::request::{QueryKind, QuerySpec};

/// Options of `humem eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// Data set folder (pairs: query/ + reference/; loop: sequence/); or
    /// a recording with --source.
    #[arg(long, required_unless_present = "source", conflicts_with = "source")]
    pub dataset: Option<PathBuf>,
    /// A recording instead of a data set folder, and how to read it.
    #[command(flatten)]
    pub recording: super::source::SourceArgs,
    /// Layers to score with: scal, scal+osrl, scal+ogtl, full-no-c (the
    /// paper's full method: evidence for only) or full.
    #[arg(long, default_value = "full")]
    pub layers: String,
    /// All five layer configurations in one table.
    #[arg(long)]
    pub ablation: bool,
    /// Degradations of the query images, e.g. B15/D80 (repeatable); the
    /// clean condition always runs first.
    #[arg(long)]
    pub degrade: Vec<Degradation>,
    /// Most queries, evenly spaced among the eligible ones.
    #[arg(long, default_value_t = 100)]
    pub max_queries: usize,
    /// Use every eligible query.
    #[arg(long)]
    pub all_queries: bool,
    /// Minimum frame gap for loop data sets (default: the data set's, else 100).
    #[arg(long)]
    pub min_gap: Option<usize>,
    /// Pose-based ground truth: largest distance, in metres.
    #[arg(long, default_value_t = 5.0)]
    pub max_distance: f64,
    /// Pose-based ground truth: largest orientation difference, in degrees.
    #[arg(long, default_value_t = 30.0)]
    pub max_angle: f64,
    /// Write every number as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a Markdown report with charts (PNG and SVG) into this folder.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Measure a running service at this URL over gRPC instead of calling
    /// the library in this process (e.g. http://127.0.0.1:50051).
    #[arg(long, value_name = "URL")]
    pub server: Option<String>,
    /// TLS to that server (`--tls-ca`, `--tls-cert`, `--tls-key`).
    #[command(flatten)]
    pub tls: humem_server::client::ClientCredentials,
    /// Where objects come from: the perception models, or the data set's
    /// instance masks (`annotations`, in-process only) to measure the object
    /// and text layers without a detector's errors.
    #[arg(long, value_enum, default_value_t = ObjectSource::Models)]
    pub objects: ObjectSource,
    /// Leave out the ORB bag-of-words baseline.
    #[arg(long)]
    pub no_baseline: bool,
    /// Send every image, stored and query, as 8-bit grey pixels (`GRAY8`,
    /// ITU-R 601 luma), as ORB-SLAM3 does; in-process only.
    #[arg(long)]
    pub grey: bool,
    /// Also stream the data set as the ORB-SLAM3 plugin does, with the
    /// ground truth standing in for geometric verification, without and
    /// with SLAM's verdicts fed back (see `verdict_replay`); in-process only.
    #[arg(long)]
    pub replay_verdicts: bool,
    /// With --replay-verdicts: share of true places that geometry rejects
    /// all the same.
    #[arg(long, default_value_t = 0.1)]
    pub wrong_rejections: f64,
    /// With --replay-verdicts: seed of the wrong rejections' draws.
    #[arg(long, default_value_t = 1)]
    pub replay_seed: u64,
    /// With --replay-verdicts: scale of the stored poses, to replay a map
    /// whose units are not metres (a monocular map: ORB-SLAM3's maps of
    /// the town loop are about 1/37 of the metres driven).
    #[arg(long, default_value_t = 1.0)]
    pub replay_pose_scale: f64,
    /// With --replay-verdicts: a further pass with other verdict settings,
    /// NAME:key=value,… (keys of [vpr.verdicts]); repeatable.
    #[arg(long)]
    pub replay_variant: Vec<super::verdict_replay::Variant>,
}

impl EvalArgs {
    /// The data set folder: `--dataset`, or the folder `run` made of
    /// `--source`.
    pub fn dataset_dir(&self) -> &std::path::Path {
        self.dataset
            .as_deref()
            .expect("clap requires --dataset or --source, and run() sets it from --source")
    }
}

/// Source of the objects of each image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ObjectSource {
    /// What the service's own models see.
    Models,
    /// The data set's ground-truth instance masks, with OCR text on them.
    Annotations,
}

fn parse_layers(name: &str) -> anyhow::Result<(&'static str, Layers)> {
    Ok(match name.to_ascii_lowercase().as_str() {
        "scal" => ("SCAL", Layers::SCAL),
        "scal+osrl" => ("SCAL+OSRL", Layers::SCAL_OSRL),
        "scal+ogtl" => ("SCAL+OGTL", Layers::SCAL_OGTL),
        "full-no-c" => ("Full (no C)", Layers::FULL_SUPPORT_ONLY),
        "full" => ("Full", Layers::FULL),
        other => {
            anyhow::bail!("--layers {other:?}: use scal, scal+osrl, scal+ogtl, full-no-c or full")
        }
    })
}

/// One method's numbers under one condition.
#[derive(Debug, Clone, Serialize)]
pub struct MethodResult {
    /// The method's name: a layer configuration (`Full`, `SCAL`, …) or
    /// `ORB-BoW`.
    pub method: String,
    /// Recall@1, Recall@5 and MRR over the queries with a match.
    #[serde(flatten)]
    pub retrieval: Retrieval,
    /// Latency over the timed queries.
    pub latency: LatencyStats,
    /// Mean milliseconds per stage over the timed queries.
    pub stages_ms: BTreeMap<String, f64>,
    /// At the operating point, over the queries with and without a match.
    pub precision: Precision,
}

/// All methods under one condition.
#[derive(Debug, Clone, Serialize)]
pub struct ConditionResult {
    /// `clean`, or the degradation applied to the queries (e.g. `B15`).
    pub condition: String,
    /// One result per method, in the table's order.
    pub results: Vec<MethodResult>,
}

/// The whole run.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// The data set's folder name.
    pub dataset: String,
    /// `pairs` or `loop`.
    pub kind: String,
    /// Where the ground truth came from (`ground_truth.json` or the poses).
    pub truth: String,
    /// Reference images in the database.
    pub references: usize,
    /// Queries with a valid match scored for recall.
    pub queries: usize,
    /// `loop` only: the frame gap candidates had to keep.
    pub min_frame_gap: Option<usize>,
    /// Queries without a valid match scored for precision.
    pub queries_without_match: usize,
    /// The operating point: threshold on the score (calibrated unless
    /// `vpr.calibration = "raw"`) and most candidates returned.
    pub threshold: f32,
    /// The score calibration, `null` or `raw`.
    pub calibration: String,
    /// Most candidates returned per query at the operating point.
    pub max_candidates: usize,
    /// Where the objects came from: `models` or `annotations`.
    pub objects: ObjectSource,
    /// Whether every image was sent as grey pixels.
    pub grey: bool,
    /// One entry per condition, `clean` first.
    pub conditions: Vec<ConditionResult>,
    /// `--replay-verdicts`: the stream without and with verdicts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verdict_replay: Option<Vec<super::verdict_replay::ReplayRow>>,
}

/// What one method gave under one condition, before it is summarised.
#[derive(Debug, Default)]
pub struct Samples {
    /// Per query with a match: the ranked reference indices and the valid matches.
    pub answers: Vec<(Vec<usize>, Vec<usize>)>,
    /// Per query, with a match or not: the ranked scores and valid flags.
    pub scored: Vec<ScoredQuery>,
    /// Latency of each timed query.
    pub latencies: Vec<Duration>,
    /// Milliseconds per stage, summed over the timed queries.
    pub stage_ms: BTreeMap<String, f64>,
}

impl Samples {
    /// Records one query's ranking: `(reference index, score)` best first,
    /// and its valid matches (`None`: the query has none).
    pub fn record(&mut self, ranked: &[(usize, f32)], matches: Option<&Vec<usize>>) {
        let valid = |r: &usize| matches.is_some_and(|m| m.contains(r));
        if let Some(m) = matches {
            self.answers
                .push((ranked.iter().map(|&(r, _)| r).collect(), m.clone()));
        }
        self.scored.push(ScoredQuery {
            ranked: ranked.iter().map(|(r, s)| (*s, valid(r))).collect(),
            has_match: matches.is_some_and(|m| !m.is_empty()),
            threshold: None,
        });
    }

    /// Recall, latency, stage times and precision at `point` from the
    /// samples, under the name `method`.
    pub fn summarise(self, method: &str, point: OperatingPoint) -> MethodResult {
        let count = self.latencies.len().max(1) as f64;
        MethodResult {
            method: method.to_string(),
            precision: precision::precision(&self.scored, point),
            retrieval: metrics::retrieval(&self.answers),
            latency: metrics::latency(&self.latencies),
            stages_ms: self
                .stage_ms
                .into_iter()
                .map(|(k, v)| (k, v / count))
                .collect(),
        }
    }
}

/// Features of one image and the perception time without decoding.
struct Perceived {
    features: Features,
    took: Duration,
    stages: Vec<(&'static str, Duration)>,
}

pub(super) fn progress(len: usize, what: &str) -> indicatif::ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>24} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// The bytes of an image, degraded (and re-encoded losslessly) if asked.
pub(super) fn image_bytes(
    path: &Path,
    degradation: Option<&Degradation>,
) -> anyhow::Result<Vec<u8>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let Some(d) = degradation else {
        return Ok(bytes);
    };
    let image = image_decode(&EncodedImage::file(&bytes))
        .with_context(|| format!("decoding {}", path.display()))?;
    let degraded = super::degrade::apply(&image, d);
    let mut png = Vec::new();
    degraded.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(png)
}

/// The request image of a file: the file itself, or its grey pixels.
fn image_input(data: Vec<u8>, grey: bool) -> anyhow::Result<ImageInput> {
    if !grey {
        return Ok(ImageInput::file(data));
    }
    let rgb = image_decode(&EncodedImage::file(&data))?;
    Ok(ImageInput {
        encoding: Encoding::Gray8,
        data: rgb.pixels().map(|p| luma(p.0)).collect(),
        width: rgb.width(),
        height: rgb.height(),
        stride: 0,
    })
}

async fn perceive_all(
    perception: &Perception,
    paths: &[PathBuf],
    degradation: Option<&Degradation>,
    annotations: Option<&Catalog>,
    grey: bool,
    what: &str,
) -> anyhow::Result<Vec<Perceived>> {
    let bar = progress(paths.len(), what);
    // The images are one camera stream, in order, as a SLAM client sends
    // its keyframes (where `perception.reuse` carries objects over).
    static STREAMS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let stream = format!(
        "{what} #{}",
        STREAMS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    );
    let mut out = Vec::with_capacity(paths.len());
    for path in paths {
        let data = image_bytes(path, degradation)?;
        let started = Instant::now();
        let extracted = perception
            .extract_in(image_input(data, grey)?, Some(&stream))
            .await
            .with_context(|| format!("perceiving {}", path.display()))?;
        let decode = extracted
            .timings
            .iter()
            .find(|(s, _)| *s == "decode")
            .map_or(Duration::ZERO, |(_, d)| *d);
        let mut features = extracted.features;
        if let Some(catalog) = annotations {
            annotations::apply(&mut features, &annotations::read_mask(path)?, catalog);
        }
        out.push(Perceived {
            features,
            took: started.elapsed().saturating_sub(decode),
            stages: extracted.timings,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(out)
}

/// Robot of the references in the in-process index.
const REFERENCE_ROBOT: &str = "reference";
/// Robot of the query frames stored for their temporal context.
const QUERY_ROBOT: &str = "query";

/// The in-process database: every reference, perceived clean once. Each
/// condition ranks through the service's own query path
/// (`pipeline::query::run`) over a real index, filled the way a SLAM
/// client fills the service (see [`LocalDatabase::condition`]).
struct LocalDatabase {
    references: Vec<Perceived>,
    /// Ground-truth objects in place of the detector's, if asked.
    annotations: Option<Catalog>,
    /// Images are sent as grey pixels.
    grey: bool,
}

/// Keyframe `index` of `robot`'s one session, as the index stores it.
pub(super) fn stored(robot: &str, index: usize, features: &Features) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: robot.into(),
            session_id: String::new(),
            keyframe_id: index as u64,
        },
        frame_id: index as u64,
        timestamp: index as f64,
        map_id: 0,
        pose: Pose::default(),
        features: features.clone(),
    }
}

impl LocalDatabase {
    /// `--replay-verdicts` on the clean images.
    async fn replay_verdicts(
        &self,
        config: &Config,
        perception: &Perception,
        args: &EvalArgs,
        dataset: &Dataset,
    ) -> anyhow::Result<Vec<super::verdict_replay::ReplayRow>> {
        let fresh;
        let queries: &[Perceived] = match dataset.kind {
            Kind::Loop => &self.references,
            Kind::Pairs => {
                fresh = perceive_all(
                    perception,
                    &dataset.queries,
                    None,
                    self.annotations.as_ref(),
                    self.grey,
                    "queries (replay)",
                )
                .await?;
                &fresh
            }
        };
        let features = |p: &[Perceived]| p.iter().map(|p| p.features.clone()).collect::<Vec<_>>();
        super::verdict_replay::replay(
            &config.vpr,
            args.dataset_dir(),
            dataset,
            &features(&self.references),
            &features(queries),
            super::verdict_replay::ReplayOptions {
                wrong_rejections: args.wrong_rejections,
                seed: args.replay_seed,
                pose_scale: args.replay_pose_scale,
            },
            &args.replay_variant,
        )
        .await
    }

    async fn build(
        perception: &Perception,
        dataset: &Dataset,
        annotations: Option<Catalog>,
        grey: bool,
    ) -> anyhow::Result<LocalDatabase> {
        let references = perceive_all(
            perception,
            &dataset.references,
            None,
            annotations.as_ref(),
            grey,
            "references",
        )
        .await?;
        Ok(LocalDatabase {
            references,
            annotations,
            grey,
        })
    }

    /// Ranks the selected queries of one condition with every method.
    ///
    /// The index holds the references a query may match: all of them for
    /// `pairs`; for `loop`, those at least the minimum frame gap before the
    /// query, added as the queries advance, as in a drive. Each selected
    /// query and its two predecessors are stored in a query session (their
    /// temporal context), and the query asks about its stored keyframe,
    /// scoped to the references, with no threshold and the whole SCAL top K
    /// (so MRR sees ranks beyond 5), as `--server` asks the service.
    #[allow(clippy::too_many_arguments)]
    async fn condition(
        &self,
        config: &Config,
        perception: &Perception,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        methods: &[(&'static str, Layers)],
        selection: &Selection,
    ) -> anyhow::Result<Vec<Samples>> {
        let condition = super::degrade::condition_name(degradation);
        // Query features: for a clean loop, the references themselves.
        let fresh;
        let queries: &[Perceived] = match (dataset.kind, degradation) {
            (Kind::Loop, None) => &self.references,
            _ => {
                fresh = perceive_all(
                    perception,
                    &dataset.queries,
                    degradation,
                    self.annotations.as_ref(),
                    self.grey,
                    &format!("queries {condition}"),
                )
                .await?;
                &fresh
            }
        };
        // References a query may match: for a loop, those of index ≤ q − gap.
        let admitted = |q: usize| match dataset.kind {
            Kind::Loop => (q + 1).saturating_sub(dataset.min_frame_gap),
            Kind::Pairs => self.references.len(),
        };
        let dim = self
            .references
            .first()
            .map_or(0, |r| r.features.descriptor.len());
        let mut out = Vec::new();
        for &(_, layers) in methods {
            let mut samples = Samples::default();
            let mut index = Index::new(dim);
            let mut next_reference = 0;
            for q in selection.all() {
                while next_reference < admitted(q).min(self.references.len()) {
                    let features = &self.references[next_reference].features;
                    index.upsert(stored(REFERENCE_ROBOT, next_reference, features));
                    next_reference += 1;
                }
                for i in (0..3).rev().filter_map(|j| q.checked_sub(j)) {
                    index.upsert(stored(QUERY_ROBOT, i, &queries[i].features));
                }
                let spec = QuerySpec {
                    session: SessionKey {
                        robot_id: QUERY_ROBOT.into(),
                        session_id: String::new(),
                    },
                    map_id: None,
                    frame_id: None,
                    keyframe_id: Some(q as u64),
                    observation: None,
                    predecessor_ids: Vec::new(),
                    scope: Scope::Listed {
                        robot_ids: vec![REFERENCE_ROBOT.into()],
                        maps: Vec::new(),
                    },
                    readable_robots: None,
                    min_frame_gap: 0,
                    top_n: config.vpr.top_k,
                    threshold: Some(0.0),
                    layers,
                    kind: QueryKind::LoopClosure,
                };
                let started = Instant::now();
                let outcome = query::run(&index, &config.vpr, &spec)
                    .with_context(|| format!("ranking query {q}"))?;
                let rank_took = started.elapsed();
                let top: Vec<(usize, f32)> = outcome
                    .candidates
                    .iter()
                    .map(|c| (c.key.keyframe_id as usize, c.score))
                    .collect();
                samples.record(&top, dataset.matches.get(&q));
                if selection.is_timed(q) {
                    samples.latencies.push(queries[q].took + rank_took);
                    for (stage, took) in queries[q].stages.iter().chain(&outcome.timings) {
                        if *stage != "decode" {
                            *samples.stage_ms.entry(stage.to_string()).or_default() +=
                                took.as_secs_f64() * 1e3;
                        }
                    }
                }
            }
            out.push(samples);
        }
        Ok(out)
    }
}

/// The queries of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Queries with a valid match (recall and precision), sorted.
    pub with_match: Vec<usize>,
    /// Queries without one (precision only), sorted.
    pub without_match: Vec<usize>,
    /// Queries of `with_match` whose latency is measured.
    pub timed: Vec<usize>,
}

impl Selection {
    /// At most `at_most` evenly spaced queries of each kind (all with
    /// `None`); the latency sample is taken from those with a match. A loop
    /// query needs at least one eligible reference (index `>= gap`).
    pub fn new(dataset: &Dataset, at_most: Option<usize>) -> Selection {
        let pick = |v: &[usize]| match at_most {
            Some(k) => metrics::evenly_spaced(v, k),
            None => v.to_vec(),
        };
        let with: Vec<usize> = dataset.matches.keys().copied().collect();
        let first = match dataset.kind {
            Kind::Loop => dataset.min_frame_gap,
            Kind::Pairs => 0,
        };
        let without: Vec<usize> = (first..dataset.queries.len())
            .filter(|q| !dataset.matches.contains_key(q))
            .collect();
        let with_match = pick(&with);
        let (_, timed_positions) = metrics::latency_sample_indices(with_match.len(), 10, 30);
        let timed = timed_positions.iter().map(|&n| with_match[n]).collect();
        Selection {
            with_match,
            without_match: pick(&without),
            timed,
        }
    }

    /// Every selected query, sorted.
    pub fn all(&self) -> Vec<usize> {
        let mut all: Vec<usize> = self
            .with_match
            .iter()
            .chain(&self.without_match)
            .copied()
            .collect();
        all.sort_unstable();
        all
    }

    /// Whether query `q` is in the latency sample.
    pub fn is_timed(&self, q: usize) -> bool {
        self.timed.contains(&q)
    }
}

/// `humem eval`.
pub async fn run(config: Config, mut args: EvalArgs) -> anyhow::Result<()> {
    // A recording becomes a data set folder first; the guard keeps a
    // temporary one until the run ends.
    let _recording = match args.recording.source.clone() {
        Some(source) => {
            let materialized = args.recording.materialize(&source)?;
            args.dataset = Some(materialized.folder.clone());
            Some(materialized)
        }
        None => None,
    };
    let rule = PoseRule {
        max_distance_m: args.max_distance,
        max_angle_deg: args.max_angle,
        min_frame_gap: args.min_gap.unwrap_or(100),
    };
    let dataset = Dataset::open(args.dataset_dir(), &rule, args.min_gap)?;
    let methods = methods(&args)?;
    let selection = Selection::new(&dataset, (!args.all_queries).then_some(args.max_queries));
    let point = OperatingPoint {
        threshold: config.vpr.threshold(),
        max_candidates: config.vpr.max_candidates,
    };
    eprintln!(
        "humem eval: {} ({:?}), {} references, {} of {} queries with a match and {} of {} without, ground truth from {}{}",
        dataset.name,
        dataset.kind,
        dataset.references.len(),
        selection.with_match.len(),
        dataset.matches.len(),
        selection.without_match.len(),
        Selection::new(&dataset, None).without_match.len(),
        dataset.truth_source,
        args.server
            .as_deref()
            .map(|s| format!(", measured through the service at {s}"))
            .unwrap_or_default()
    );
    let mut backend = Backend::open(&config, &args, &dataset).await?;
    let baseline = if args.no_baseline {
        None
    } else {
        Some(super::baseline::OrbBaseline::build(&dataset)?)
    };

    let mut conditions = vec![None];
    conditions.extend(args.degrade.iter().map(Some));
    let mut report = EvalReport {
        dataset: dataset.name.clone(),
        kind: format!("{:?}", dataset.kind).to_lowercase(),
        truth: dataset.truth_source.clone(),
        references: dataset.references.len(),
        queries: selection.with_match.len(),
        queries_without_match: selection.without_match.len(),
        threshold: point.threshold,
        calibration: format!("{:?}", config.vpr.calibration).to_lowercase(),
        max_candidates: point.max_candidates,
        min_frame_gap: (dataset.kind == Kind::Loop).then_some(dataset.min_frame_gap),
        objects: args.objects,
        grey: args.grey,
        conditions: Vec::new(),
        verdict_replay: None,
    };
    for degradation in conditions {
        let condition = super::degrade::condition_name(degradation);
        let samples = backend
            .condition(&config, &dataset, degradation, &methods, &selection)
            .await?;
        let mut results: Vec<MethodResult> = methods
            .iter()
            .zip(samples)
            .map(|(&(method, _), s)| s.summarise(method, point))
            .collect();
        if let Some(baseline) = &baseline {
            let samples =
                baseline.condition(&dataset, degradation, &selection, config.vpr.top_k)?;
            // Bag-of-words scores have no calibrated threshold: it answers
            // every query, and its threshold-free figures (recall at 100 %
            // precision, the curve) are the comparable ones.
            let always = OperatingPoint {
                threshold: f32::NEG_INFINITY,
                ..point
            };
            results.push(samples.summarise(super::baseline::METHOD, always));
        }
        report
            .conditions
            .push(ConditionResult { condition, results });
    }
    if args.replay_verdicts {
        if !(0.0..=1.0).contains(&args.wrong_rejections) {
            anyhow::bail!("--wrong-rejections must be in [0, 1]");
        }
        if !(args.replay_pose_scale.is_finite() && args.replay_pose_scale > 0.0) {
            anyhow::bail!("--replay-pose-scale must be a finite number > 0");
        }
        let rows = match &mut backend {
            Backend::Local(local) => {
                let (perception, database) = &**local;
                database
                    .replay_verdicts(&config, perception, &args, &dataset)
                    .await?
            }
            Backend::Remote(remote) => {
                if !args.replay_variant.is_empty() {
                    anyhow::bail!("--replay-variant runs in-process only: a running service has one configuration");
                }
                remote
                    .replay_verdicts(
                        &config.vpr,
                        args.dataset_dir(),
                        &dataset,
                        super::verdict_replay::ReplayOptions {
                            wrong_rejections: args.wrong_rejections,
                            seed: args.replay_seed,
                            pose_scale: args.replay_pose_scale,
                        },
                    )
                    .await?
            }
        };
        report.verdict_replay = Some(rows);
    }
    if let Backend::Remote(remote) = &mut backend {
        let erased = remote.clean_up().await?;
        eprintln!("humem eval: removed the run's {erased} keyframes from the server");
    }
    print_table(&report);
    write_outputs(&report, &args)
}

/// The methods compared: the ablation's five, or the one asked for.
fn methods(args: &EvalArgs) -> anyhow::Result<Vec<(&'static str, Layers)>> {
    if args.ablation {
        ["scal", "scal+osrl", "scal+ogtl", "full-no-c", "full"]
            .iter()
            .map(|l| parse_layers(l))
            .collect()
    } else {
        Ok(vec![parse_layers(&args.layers)?])
    }
}

/// Where the queries are ranked: in this process, or by a running service.
enum Backend {
    Local(Box<(Perception, LocalDatabase)>),
    Remote(Box<super::remote::Remote>),
}

impl Backend {
    /// Loads the models and the references here, or inserts the references
    /// into the service at `--server`.
    async fn open(config: &Config, args: &EvalArgs, dataset: &Dataset) -> anyhow::Result<Backend> {
        match &args.server {
            None => {
                let perception = Perception::load(&config.perception, config.store.scene_top_k)
                    .context("loading the perception models (run scripts/setup-models.sh)")?;
                let annotations = match args.objects {
                    ObjectSource::Models => None,
                    ObjectSource::Annotations => Some(Catalog::find(args.dataset_dir())?),
                };
                let database =
                    LocalDatabase::build(&perception, dataset, annotations, args.grey).await?;
                Ok(Backend::Local(Box::new((perception, database))))
            }
            Some(url) => {
                if args.grey {
                    anyhow::bail!("--grey runs in-process only, not with --server");
                }
                if args.objects == ObjectSource::Annotations {
                    anyhow::bail!("--objects annotations replaces perception, so it runs in-process only, not with --server");
                }
                let mut remote =
                    super::remote::Remote::connect(url, &args.tls, dataset, config.vpr.top_k)
                        .await?;
                remote.insert_references(dataset).await?;
                Ok(Backend::Remote(Box::new(remote)))
            }
        }
    }

    /// The selected queries of one condition, ranked with every method.
    async fn condition(
        &mut self,
        config: &Config,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        methods: &[(&'static str, Layers)],
        selection: &Selection,
    ) -> anyhow::Result<Vec<Samples>> {
        match self {
            Backend::Local(local) => {
                let (perception, database) = &**local;
                database
                    .condition(config, perception, dataset, degradation, methods, selection)
                    .await
            }
            Backend::Remote(remote) => {
                remote
                    .condition(dataset, degradation, methods, selection)
                    .await
            }
        }
    }
}

/// Writes `--json` and the `--report` folder (summary, results, charts).
fn write_outputs(report: &EvalReport, args: &EvalArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(dir) = &args.report {
        std::fs::create_dir_all(dir)?;
        std::fs::write(dir.join("summary.md"), markdown(report))?;
        std::fs::write(
            dir.join("results.json"),
            serde_json::to_string_pretty(report)?,
        )?;
        let charts = super::plots::write_all(report, dir)?;
        eprintln!(
            "humem eval: report in {} (summary.md, results.json, {})",
            dir.display(),
            charts.join(", ")
        );
    }
    Ok(())
}

fn rows(report: &EvalReport) -> Vec<String> {
    let mut rows = Vec::new();
    for c in &report.conditions {
        for r in &c.results {
            rows.push(format!(
                "| {} | {} | {:.3} | {:.3} | {:.3} | {:.1} | {:.1} | {:.1} |",
                c.condition,
                r.method,
                r.retrieval.recall_at_1,
                r.retrieval.recall_at_5,
                r.retrieval.mrr,
                r.latency.mean_ms,
                r.latency.median_ms,
                r.latency.p95_ms
            ));
        }
    }
    rows
}

fn precision_rows(report: &EvalReport) -> Vec<String> {
    let mut rows = Vec::new();
    for c in &report.conditions {
        for r in &c.results {
            let p = &r.precision;
            rows.push(format!(
                "| {} | {} | {} | {} | {} | {} | {} ({:.1} %) | {:.3} | {:.3} | {:.3} |",
                c.condition,
                r.method,
                p.queries,
                p.queries - p.with_match,
                p.answered,
                p.false_top,
                p.false_no_match,
                p.false_alarm_rate * 100.0,
                p.candidate_precision,
                p.recall_at_threshold,
                p.recall_at_full_precision,
            ));
        }
    }
    rows
}

const HEADER: &str = "| condition | method | R@1 | R@5 | MRR | mean ms | median ms | p95 ms |\n| --- | --- | --- | --- | --- | --- | --- | --- |";

const PRECISION_HEADER: &str = "| condition | method | queries | without match | answered | false top-1 | false alarms (no match) | candidate precision | recall at threshold | recall at 100 % precision |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |";

fn operating_point(report: &EvalReport) -> String {
    format!(
        "operating point: {} calibration, threshold {:.2}, at most {} candidates; {} queries without a match scored for precision (ORB-BoW answers every query)",
        report.calibration, report.threshold, report.max_candidates, report.queries_without_match
    )
}

fn print_table(report: &EvalReport) {
    println!(
        "{} ({}, {} references, {} queries, ground truth from {})",
        report.dataset, report.kind, report.references, report.queries, report.truth
    );
    println!("{HEADER}");
    for row in rows(report) {
        println!("{row}");
    }
    println!("\n{}", operating_point(report));
    println!("{PRECISION_HEADER}");
    for row in precision_rows(report) {
        println!("{row}");
    }
    if let Some(rows) = &report.verdict_replay {
        println!("\n{}", replay_heading(report));
        print!("{}", super::verdict_replay::table(rows));
    }
}

fn replay_heading(report: &EvalReport) -> String {
    format!(
        "Streamed as the ORB-SLAM3 plugin streams, the ground truth as geometric verification (Full, at the {}):",
        operating_point(report)
    )
}

fn markdown(report: &EvalReport) -> String {
    let mut md = format!(
        "# HuMem evaluation: {}\n\n{} data set, {} references, {} queries (evenly spaced among the eligible ones), ground truth from {}{}.\nLatency: 30 evenly spaced queries after 10 warm-ups, perception without decoding plus ranking.\n\n{HEADER}\n",
        report.dataset,
        report.kind,
        report.references,
        report.queries,
        report.truth,
        report
            .min_frame_gap
            .map(|g| format!(", minimum frame gap {g}"))
            .unwrap_or_default()
    );
    for row in rows(report) {
        md.push_str(&row);
        md.push('\n');
    }
    md.push_str(&format!(
        "\nPrecision at the {}.\n\n{PRECISION_HEADER}\n",
        operating_point(report)
    ));
    for row in precision_rows(report) {
        md.push_str(&row);
        md.push('\n');
    }
    if let Some(rows) = &report.verdict_replay {
        md.push_str(&format!(
            "\n{}\n\n{}",
            replay_heading(report),
            super::verdict_replay::table(rows)
        ));
    }
    md.push_str(
        "\n![Recall@1 against median latency](accuracy_latency.png)\n\n![Recall per condition](recall_per_condition.png)\n\n![Precision against recall](precision_recall.png)\n",
    );
    md
}
