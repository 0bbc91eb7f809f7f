//! `humem eval`: recall and latency on a data set, the paper's way.
//!
//! The run itself and nothing else: it opens the data set and the backend
//! that ranks the queries (the in-process database of `local`, or
//! a running service through [`crate::remote`]), asks the selected queries
//! ([`crate::protocol`]) under every condition with every method, the ORB
//! baseline ([`crate::baseline`]) beside them, and writes what it found
//! ([`crate::report`], [`crate::plots`]). The end-to-end test
//! `eval_through_the_service_ranks_as_the_library_does` checks that a
//! running service gives the same numbers as the library in process.
//! Precision is taken at the configured operating point (threshold and
//! `max_candidates` of `[vpr]`, see [`crate::precision`]).

use anyhow::Context;

use crate::annotations::Catalog;
use crate::args::{methods, EvalArgs, ObjectSource};
use crate::baseline::{self, OrbBaseline};
use crate::dataset::Dataset;
use crate::degrade::{self, Degradation};
use crate::local::LocalDatabase;
use crate::plots;
use crate::precision::OperatingPoint;
use crate::protocol::{Samples, Selection};
use crate::remote::Remote;
use crate::report::{markdown, print_table, ConditionResult, EvalReport, MethodResult};
use crate::truth::{Kind, PoseRule};
use crate::verdict_replay::ReplayOptions;
use humem_core::vpr::params::Layers;
use humem_perception::Perception;
use humem_server::config::Config;

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
        Some(OrbBaseline::build(&dataset)?)
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
        let condition = degrade::condition_name(degradation);
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
            results.push(samples.summarise(baseline::METHOD, always));
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
        if !(args.replay_pose_drift.is_finite() && args.replay_pose_drift >= 0.0) {
            anyhow::bail!("--replay-pose-drift must be a finite number >= 0");
        }
        if args.replay_trajectory.is_some()
            && (args.replay_pose_drift != 0.0 || args.replay_pose_scale != 1.0)
        {
            anyhow::bail!("--replay-trajectory replays the poses SLAM sent: --replay-pose-drift and --replay-pose-scale do not apply");
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
                if args.replay_trajectory.is_some() {
                    anyhow::bail!("--replay-trajectory runs in-process only: leave out --server");
                }
                remote
                    .replay_verdicts(
                        &config.vpr,
                        args.dataset_dir(),
                        &dataset,
                        ReplayOptions {
                            wrong_rejections: args.wrong_rejections,
                            seed: args.replay_seed,
                            pose_scale: args.replay_pose_scale,
                            pose_drift: args.replay_pose_drift,
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

/// Where the queries are ranked: in this process, or by a running service.
enum Backend {
    Local(Box<(Perception, LocalDatabase)>),
    Remote(Box<Remote>),
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
                let mut remote = Remote::connect(url, &args.tls, dataset, config.vpr.top_k).await?;
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
        let charts = plots::write_all(report, dir)?;
        eprintln!(
            "humem eval: report in {} (summary.md, results.json, {})",
            dir.display(),
            charts.join(", ")
        );
    }
    Ok(())
}
