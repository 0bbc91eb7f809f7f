//! The ORB bag-of-words baseline, run beside HuMem-VPR in the same
//! evaluation for an honest comparison: the retrieval ORB-SLAM3 does
//! natively (see [`humem_orb_bow`]).
//!
//! Same queries, same ground truth, same eligibility and the same latency
//! protocol as the other methods: its latency is ORB extraction (decoding
//! excluded) plus scoring every reference and sorting. It always runs in
//! this process, also with `--server`, since the service does not implement
//! it. It has no temporal context, as DBoW2's database has none.

use std::time::{Duration, Instant};

use anyhow::Context;

use super::dataset::Dataset;
use super::degrade::Degradation;
use super::images::image_bytes;
use super::progress::progress;
use super::protocol::{Samples, Selection};
use super::truth::Kind;
use humem_orb_bow::{self as orb_bow, BowParams, Descriptor, OrbBowIndex, OrbParams};

/// Name of the method in reports.
pub const METHOD: &str = "ORB-BoW";

/// The ORB features of one image and the time taken without decoding.
struct Extracted {
    descriptors: Vec<Descriptor>,
    took: Duration,
}

fn extract_all(
    paths: &[std::path::PathBuf],
    degradation: Option<&Degradation>,
    params: &OrbParams,
    what: &str,
) -> anyhow::Result<Vec<Extracted>> {
    let bar = progress(paths.len(), what);
    let mut out = Vec::with_capacity(paths.len());
    for path in paths {
        let bytes = image_bytes(path, degradation)?;
        let gray = image::load_from_memory(&bytes)
            .with_context(|| format!("decoding {}", path.display()))?
            .to_luma8();
        let started = Instant::now();
        let descriptors = orb_bow::extract(&gray, params);
        out.push(Extracted {
            descriptors,
            took: started.elapsed(),
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(out)
}

/// A vocabulary and database trained on a data set's references.
pub struct OrbBaseline {
    params: OrbParams,
    index: OrbBowIndex,
    references: Vec<Extracted>,
}

impl OrbBaseline {
    /// Extracts the references' features and trains the vocabulary on them.
    pub fn build(dataset: &Dataset) -> anyhow::Result<OrbBaseline> {
        let params = OrbParams::default();
        let references = extract_all(&dataset.references, None, &params, "references (ORB)")?;
        let descriptors: Vec<Vec<Descriptor>> =
            references.iter().map(|r| r.descriptors.clone()).collect();
        let started = Instant::now();
        let index = OrbBowIndex::build(&descriptors, &BowParams::default());
        eprintln!(
            "humem eval: ORB-BoW vocabulary of {} words trained on {} references in {:.1} s",
            index.vocabulary().num_words(),
            references.len(),
            started.elapsed().as_secs_f64()
        );
        Ok(OrbBaseline {
            params,
            index,
            references,
        })
    }

    /// Ranks the selected queries of one condition.
    pub fn condition(
        &self,
        dataset: &Dataset,
        degradation: Option<&Degradation>,
        selection: &Selection,
        top_k: usize,
    ) -> anyhow::Result<Samples> {
        let condition = super::degrade::condition_name(degradation);
        let fresh;
        let queries: &[Extracted] = match (dataset.kind, degradation) {
            (Kind::Loop, None) => &self.references,
            _ => {
                fresh = extract_all(
                    &dataset.queries,
                    degradation,
                    &self.params,
                    &format!("queries {condition} (ORB)"),
                )?;
                &fresh
            }
        };
        let mut samples = Samples::default();
        for q in selection.all() {
            let started = Instant::now();
            let scores = self.index.score_all(&queries[q].descriptors);
            let mut ranked: Vec<usize> = (0..scores.len())
                .filter(|&r| match dataset.kind {
                    Kind::Loop => r + dataset.min_frame_gap <= q,
                    Kind::Pairs => true,
                })
                .collect();
            ranked.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
            ranked.truncate(top_k);
            let scoring = started.elapsed();
            let ranked: Vec<(usize, f32)> = ranked.iter().map(|&r| (r, scores[r])).collect();
            samples.record(&ranked, dataset.matches.get(&q));
            if selection.is_timed(q) {
                samples.latencies.push(queries[q].took + scoring);
                *samples.stage_ms.entry("orb".into()).or_default() +=
                    queries[q].took.as_secs_f64() * 1e3;
                *samples.stage_ms.entry("bow".into()).or_default() += scoring.as_secs_f64() * 1e3;
            }
        }
        Ok(samples)
    }
}
