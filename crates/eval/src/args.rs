//! The options of `humem eval` and the methods they name.
//!
//! A leaf module of plain data (clap parses it, the run and the in-process
//! database read it), apart from the run, so that what reads the options
//! does not have to take in the run that uses it.

use std::path::PathBuf;

use serde::Serialize;

use crate::degrade::Degradation;
use crate::replay_variant::Variant;
use crate::source::SourceArgs;
use humem_core::vpr::params::Layers;

/// Options of `humem eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// Data set folder (pairs: query/ + reference/; loop: sequence/); or
    /// a recording with --source.
    #[arg(long, required_unless_present = "source", conflicts_with = "source")]
    pub dataset: Option<PathBuf>,
    /// A recording instead of a data set folder, and how to read it.
    #[command(flatten)]
    pub recording: SourceArgs,
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
    /// With --replay-verdicts: send the poses as an odometry drifting by
    /// this share of the path would (a seeded random walk in heading and
    /// scale per metre driven; 0.03: a revisit after a 200 m loop lies
    /// about 6 m from its first visit). 0: the data set's poses.
    #[arg(long, default_value_t = 0.0)]
    pub replay_pose_drift: f64,
    /// With --replay-verdicts: a further pass with other settings,
    /// NAME:key=value,… (keys of [vpr.verdicts], max_drift_ratio and
    /// leave_out_rivals_beyond_drift);
    /// repeatable.
    #[arg(long)]
    pub replay_variant: Vec<Variant>,
    /// With --replay-verdicts: replay the keyframes, poses, pose updates,
    /// erasures and loop queries that the ORB-SLAM3 plugin sent, as its
    /// sent log (`HuMem.SentLog`) recorded them, instead of every frame at
    /// the data set's poses; a loop data set with a TUM pose file (its
    /// timestamps match keyframes to images); in-process only.
    #[arg(long, value_name = "SENT_LOG")]
    pub replay_trajectory: Option<PathBuf>,
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

/// The methods compared: the ablation's five, or the one asked for.
pub(crate) fn methods(args: &EvalArgs) -> anyhow::Result<Vec<(&'static str, Layers)>> {
    if args.ablation {
        ["scal", "scal+osrl", "scal+ogtl", "full-no-c", "full"]
            .iter()
            .map(|l| parse_layers(l))
            .collect()
    } else {
        Ok(vec![parse_layers(&args.layers)?])
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: EvalArgs,
    }

    fn parse(extra: &[&str]) -> EvalArgs {
        let argv = ["humem-eval", "--dataset", "toy"].iter().chain(extra);
        Cli::try_parse_from(argv).unwrap().args
    }

    #[test]
    fn layer_names_are_case_blind_and_checked() {
        assert_eq!(
            parse_layers("SCAL+OSRL").unwrap(),
            ("SCAL+OSRL", Layers::SCAL_OSRL)
        );
        assert_eq!(
            parse_layers("full-no-c").unwrap(),
            ("Full (no C)", Layers::FULL_SUPPORT_ONLY)
        );
        assert!(parse_layers("osrl").is_err());
    }

    #[test]
    fn the_ablation_compares_five_configurations() {
        let one = methods(&parse(&[])).unwrap();
        assert_eq!(one, [("Full", Layers::FULL)]);
        let names: Vec<&str> = methods(&parse(&["--ablation"]))
            .unwrap()
            .iter()
            .map(|(name, _)| *name)
            .collect();
        assert_eq!(
            names,
            ["SCAL", "SCAL+OSRL", "SCAL+OGTL", "Full (no C)", "Full"]
        );
        assert!(methods(&parse(&["--layers", "nope"])).is_err());
    }
}
