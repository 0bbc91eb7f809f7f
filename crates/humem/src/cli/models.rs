//! `humem models check`: before a model meets a robot, every configured
//! model is loaded, its inputs and outputs are compared with the
//! configuration and the store's descriptor length, one image is run
//! through it, and what was found is printed; any mismatch makes the
//! command fail, naming the model, the tensor and what was expected. The
//! checks are `humem_perception::check`'s; the server runs the same graph
//! checks as it loads the models.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};

use humem_perception::check::{self, Expected, ModelReport};
use humem_perception::image::{decode, EncodedImage};
use humem_server::config::Config;

/// What `humem models` does.
#[derive(Debug, Subcommand)]
pub enum ModelsCommand {
    /// Load every configured model (descriptor, scene, detector, OCR),
    /// check its inputs and outputs against the configuration and the
    /// store's descriptor length, run one image through it and print what
    /// came out; exit non-zero on any mismatch.
    Check(CheckArgs),
}

/// Flags of `humem models check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// Run this picture (JPEG or PNG) through the models instead of a
    /// synthetic street scene.
    #[arg(long)]
    pub image: Option<PathBuf>,
}

/// Runs a `humem models` command.
pub fn run(command: ModelsCommand, config: &Config) -> anyhow::Result<()> {
    let ModelsCommand::Check(args) = command;
    let perception = &config.perception;
    println!(
        "ONNX Runtime  {}",
        perception.onnxruntime_library().display()
    );
    println!("models_dir    {}", perception.models_dir.display());
    if !perception.enabled {
        println!("              perception.enabled = false: the server loads none of these; checked anyway");
    }
    let expected = store_expectations(config);
    let image = match &args.image {
        Some(path) => {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            decode(&EncodedImage::file(&bytes))
                .with_context(|| format!("decoding {}", path.display()))?
        }
        None => check::synthetic_image(),
    };
    println!(
        "image         {} ({}x{})",
        args.image
            .as_ref()
            .map_or("synthetic street scene".into(), |p| p.display().to_string()),
        image.width(),
        image.height()
    );
    let reports = check::check_models(perception, &expected, &image)?;
    for report in &reports {
        print_report(report);
    }
    let failed: Vec<String> = reports
        .iter()
        .filter_map(|r| r.outcome.as_ref().err())
        .map(|e| format!("  {e}"))
        .collect();
    println!();
    if failed.is_empty() {
        println!("all {} models fit the configuration", reports.len());
        return Ok(());
    }
    anyhow::bail!(
        "{} of {} models do not fit the configuration:\n{}",
        failed.len(),
        reports.len(),
        failed.join("\n")
    )
}

/// The descriptor lengths the store needs: `store.descriptor_dim`, and the
/// length an existing store records (read without creating one).
fn store_expectations(config: &Config) -> Vec<Expected> {
    let mut expected = Vec::new();
    let dim = config.store.descriptor_dim;
    if dim > 0 {
        expected.push(Expected {
            len: dim,
            source: "store.descriptor_dim".into(),
        });
    }
    let dir = &config.store.data_dir;
    match humem_store::recorded_dim(dir) {
        Ok(Some(len)) => {
            println!("store         {}: {len}-value descriptors", dir.display());
            expected.push(Expected {
                len,
                source: format!(
                    "the store in {}; start a new data directory when the descriptor model changes",
                    dir.display()
                ),
            });
        }
        Ok(None) => println!(
            "store         {}: no descriptors stored yet{}",
            dir.display(),
            if dim > 0 {
                format!(" (store.descriptor_dim = {dim})")
            } else {
                " (the first keyframe fixes their length)".into()
            }
        ),
        Err(e) => println!(
            "store         {}: not read ({e}; is a server running on it?)",
            dir.display()
        ),
    }
    expected
}

fn print_report(report: &ModelReport) {
    println!();
    let verdict = if report.outcome.is_ok() {
        "ok"
    } else {
        "DOES NOT FIT"
    };
    println!("{}  {verdict}", report.model);
    if let Some(file) = &report.file {
        let precision = match report.precision {
            humem_perception::config::Precision::Fp32 => "fp32",
            humem_perception::config::Precision::Int8 => "int8",
        };
        println!("  file    {} ({precision})", file.display());
    }
    if let Some(io) = &report.io {
        for input in &io.inputs {
            println!("  input   {input}");
        }
        for output in &io.outputs {
            println!("  output  {output}");
        }
    }
    for note in &report.notes {
        println!("  note    {note}");
    }
    for line in &report.ran {
        println!("  ran     {line}");
    }
    if let Err(e) = &report.outcome {
        println!("  error   {e}");
    }
}
