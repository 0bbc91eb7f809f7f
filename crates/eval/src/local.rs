//! The in-process database of `humem eval`: every reference perceived by
//! this process's models, and each condition's queries ranked through the
//! service's own query path over a real in-memory index.
//!
//! The references and the query frames go into the index as a SLAM client
//! would store them, and each selected query is answered by
//! `humem_server::pipeline::query::run` (eligibility, scope, temporal
//! context, HuMem-VPR ranking) with the layers of each configuration
//! (ablations are configurations, not code). A query's latency is its
//! perception without decoding plus its ranking; building the database is
//! not counted. Apart from the run, which only chooses between this and a
//! running service ([`crate::remote`]).

use std::borrow::Cow;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;

use crate::annotations::{self, Catalog};
use crate::args::EvalArgs;
use crate::dataset::{self, Dataset};
use crate::degrade::{self, Degradation};
use crate::images::{image_bytes, image_input};
use crate::keyframes::stored;
use crate::progress::progress;
use crate::protocol::{Samples, Selection};
use crate::replay_rows::ReplayRow;
use crate::sent_log;
use crate::truth::Kind;
use crate::verdict_replay::{self, ReplayOptions};
use humem_core::index::Index;
use humem_core::keyframe::{Features, SessionKey};
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::params::Layers;
use humem_perception::Perception;
use humem_server::config::Config;
use humem_server::pipeline::query;
use humem_server::pipeline::request::{QueryKind, QuerySpec};

/// Features of one image and the perception time without decoding.
#[derive(Clone)]
struct Perceived {
    features: Features,
    took: Duration,
    stages: Vec<(&'static str, Duration)>,
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
pub(crate) struct LocalDatabase {
    references: Vec<Perceived>,
    /// Ground-truth objects in place of the detector's, if asked.
    annotations: Option<Catalog>,
    /// Images are sent as grey pixels.
    grey: bool,
}

impl LocalDatabase {
    /// The query features of `dataset` under `degradation`: for a clean
    /// loop the references themselves (its queries are its own frames),
    /// otherwise its query images perceived anew (`what` names them on the
    /// progress bar).
    async fn queries(
        &self,
        perception: &Perception,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        what: &str,
    ) -> anyhow::Result<Cow<'_, [Perceived]>> {
        if dataset.kind == Kind::Loop && degradation.is_none() {
            return Ok(Cow::Borrowed(&self.references));
        }
        let perceived = perceive_all(
            perception,
            &dataset.queries,
            degradation,
            self.annotations.as_ref(),
            self.grey,
            what,
        )
        .await?;
        Ok(Cow::Owned(perceived))
    }

    /// `--replay-verdicts` on the clean images.
    pub(crate) async fn replay_verdicts(
        &self,
        config: &Config,
        perception: &Perception,
        args: &EvalArgs,
        dataset: &Dataset,
    ) -> anyhow::Result<Vec<ReplayRow>> {
        let features = |p: &[Perceived]| p.iter().map(|p| p.features.clone()).collect::<Vec<_>>();
        let options = ReplayOptions {
            wrong_rejections: args.wrong_rejections,
            seed: args.replay_seed,
            pose_scale: args.replay_pose_scale,
            pose_drift: args.replay_pose_drift,
        };
        if let Some(log) = &args.replay_trajectory {
            let dir = args.dataset_dir();
            if dataset.kind != Kind::Loop {
                anyhow::bail!(
                    "--replay-trajectory replays a loop data set (sequence/), not {}",
                    dataset.name
                );
            }
            let Some(timestamps) = dataset::timestamps(dir, "sequence")? else {
                anyhow::bail!(
                    "--replay-trajectory matches keyframes to images by timestamp: {} has no sequence_poses.txt",
                    dir.display()
                );
            };
            let steps = sent_log::read(log, &timestamps)?;
            let references = features(&self.references);
            return verdict_replay::replay_steps(
                &config.vpr,
                dataset,
                &references,
                &references,
                &steps,
                options,
                &args.replay_variant,
            )
            .await;
        }
        let queries = self
            .queries(perception, dataset, None, "queries (replay)")
            .await?;
        verdict_replay::replay(
            &config.vpr,
            args.dataset_dir(),
            dataset,
            &features(&self.references),
            &features(&queries),
            options,
            &args.replay_variant,
        )
        .await
    }

    pub(crate) async fn build(
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
    pub(crate) async fn condition(
        &self,
        config: &Config,
        perception: &Perception,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        methods: &[(&'static str, Layers)],
        selection: &Selection,
    ) -> anyhow::Result<Vec<Samples>> {
        let condition = degrade::condition_name(degradation);
        let queries = self
            .queries(
                perception,
                dataset,
                degradation,
                &format!("queries {condition}"),
            )
            .await?;
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
            keep_graph_as_the_server_would(config, &mut index, self.references.len())?;
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
                    exact: false,
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

/// Keeps a neighbour graph in `index`, as the server's store does
/// (`store.neighbour_graph`, shortened to `store.neighbour_graph_length`),
/// where the data set's `references` reach `vpr.approximate_from`, so
/// that queries take their candidates from it as a server's would: with
/// the default switch point no data set does, and a run with
/// `HUMEM_VPR__APPROXIMATE_FROM=1` measures the graph on real images.
fn keep_graph_as_the_server_would(
    config: &Config,
    index: &mut Index,
    references: usize,
) -> anyhow::Result<()> {
    if config.store.neighbour_graph
        && !config.vpr.exact
        && references >= config.vpr.approximate_from
    {
        index.shorten_graph_rows(config.store.neighbour_graph_length);
        index
            .keep_neighbour_graph(None)
            .context("starting the neighbour graph")?;
        if config.store.map_graphs {
            index.keep_map_graphs(config.vpr.approximate_from);
        }
    }
    Ok(())
}
