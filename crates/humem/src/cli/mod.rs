//! The command line: `humem serve` and the client commands.
//!
//! The client reads and prints the API's messages in the proto3 JSON mapping
//! (field names in lowerCamelCase, 64-bit ids as strings or numbers), so what
//! a script sends is exactly what the `.proto` documents.
//!
//! This module holds the command enum and hands each client command to its
//! call in [`client`]; the flag groups the commands share are in [`args`],
//! a leaf both use, so no child module reaches back up into this one.

pub mod args;
pub(crate) mod client;
#[cfg(feature = "eval")]
pub mod cluster_bench;
pub mod export;
pub mod load;
pub mod models;
pub mod probe;
pub mod token;

use std::path::PathBuf;

use anyhow::bail;
use clap::{Parser, Subcommand};

pub use args::{Output, ServeArgs, ServerArg, SessionArgs};

/// HuMem: semantic place recognition for visual SLAM.
#[derive(Debug, Parser)]
#[command(name = "humem", version, about)]
pub struct Cli {
    /// TOML configuration file (settings can also come from HUMEM_* variables,
    /// e.g. HUMEM_STORE__DATA_DIR).
    #[arg(long, global = true, env = "HUMEM_CONFIG")]
    pub config: Option<PathBuf>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the gRPC service.
    Serve(ServeArgs),
    /// Store keyframes read as JSON (`Keyframe` messages: one array, or one
    /// object per line) from a file or `-` for standard input.
    Insert {
        #[command(flatten)]
        server: ServerArg,
        /// File of keyframes, `-` for standard input.
        #[arg(default_value = "-")]
        file: PathBuf,
        /// Keyframes per InsertBatch call.
        #[arg(long, default_value_t = 256)]
        batch: usize,
    },
    /// Run queries read as JSON (`QueryRequest` messages) and print the answers.
    Query {
        #[command(flatten)]
        server: ServerArg,
        /// File of queries, `-` for standard input.
        #[arg(default_value = "-")]
        file: PathBuf,
        /// Output: `json` (one QueryResponse per line) or `table`; default:
        /// table on a terminal, JSON otherwise.
        #[arg(long)]
        output: Option<Output>,
    },
    /// Remove keyframes.
    Erase {
        #[command(flatten)]
        server: ServerArg,
        #[command(flatten)]
        session: SessionArgs,
        /// Keyframe ids.
        #[arg(required = true)]
        keyframe_ids: Vec<u64>,
    },
    /// Remove every keyframe of a map.
    ResetMap {
        #[command(flatten)]
        server: ServerArg,
        #[command(flatten)]
        session: SessionArgs,
        #[arg(long)]
        map: u64,
    },
    /// Remove every keyframe of a session.
    ResetSession {
        #[command(flatten)]
        server: ServerArg,
        #[command(flatten)]
        session: SessionArgs,
    },
    /// Print what the store holds.
    Stats {
        #[command(flatten)]
        server: ServerArg,
    },
    /// Print every keyframe of a stopped server's store (ids, map, pose;
    /// one JSON object per line), read from its data directory.
    Export {
        /// Data directory of the store (no server may be running on it).
        #[arg(long)]
        data_dir: PathBuf,
    },
    /// Measure the service's parts and print a table.
    #[cfg(feature = "eval")]
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Recall@1/@5, MRR and latency on a data set, the paper's way (ablations
    /// and degradations as options).
    #[cfg(feature = "eval")]
    Eval(humem_eval::args::EvalArgs),
    /// Streams a recording (a bag, a TUM, EuRoC or KITTI folder, a HuMem
    /// folder) into a running server as a robot would, and prints the loop
    /// candidates it got, scored against the recording's poses.
    #[cfg(feature = "eval")]
    Ingest(humem_eval::ingest::IngestArgs),
    /// Text recall of the OCR on data sets with poses and sign positions:
    /// the share of frames with a distinctive sign in view where OCR reads
    /// it, and OCR time per image.
    #[cfg(feature = "eval")]
    TextRecall(humem_eval::text_recall::TextRecallArgs),
    /// Check a running server's plain-HTTP probe endpoint (exit 0 when it
    /// answers 200): for container health checks.
    Probe {
        /// The endpoint: `/readyz` (serving) or `/healthz` (alive) on the
        /// metrics listener.
        #[arg(long, default_value = "http://127.0.0.1:9464/readyz")]
        url: String,
    },
    /// Manage the bearer tokens robots authenticate with.
    #[command(subcommand)]
    Token(token::TokenCommand),
    /// Check the configured models before they meet a robot.
    #[command(subcommand)]
    Models(models::ModelsCommand),
    /// Drive a running server from simulated robots and print the achieved
    /// rate, latency percentiles, superseded queries and errors.
    Load(load::LoadArgs),
}

/// What `humem bench` measures.
#[cfg(feature = "eval")]
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// The perception models: latency per batch size, and the throughput
    /// gain of batching under concurrent clients against unbatched inference.
    Perception(humem_eval::perception_bench::PerceptionBench),
    /// A SCAL-only query on large synthetic stores (100k and 1M keyframes by
    /// default) against an exact f32 dot-product scan, on one core and all.
    Scan(humem_eval::scan_bench::ScanBench),
    /// The neighbour graph (the approximate first stage of a large query)
    /// against the exact pass: build time, memory, and per number of
    /// candidates the latency and the recall of the exact top-1 and top-5.
    Graph(humem_eval::graph_bench::GraphBench),
    /// Opening a large store from its index snapshot and journal against
    /// rebuilding the index from every stored record.
    Restart(humem_eval::restart_bench::RestartBench),
    /// Cluster mode against running replicas: replica lag under a fleet's
    /// insert rate, query throughput per replica count, and (with
    /// `--failover`) writes lost while replicas and NATS nodes are killed.
    Cluster(crate::cli::cluster_bench::ClusterBench),
    /// What stored verification verdicts add to a query's cost as they
    /// pile up in one session, against verdicts off in the same run.
    Verdicts(humem_eval::verdict_bench::VerdictBench),
}

/// Runs a client command.
pub async fn run_client(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Load(args) => load::run(args).await?,
        Command::Serve(_)
        | Command::Export { .. }
        | Command::Token(_)
        | Command::Probe { .. }
        | Command::Models(_) => {
            bail!("not a client command")
        }
        #[cfg(feature = "eval")]
        Command::Bench(_) | Command::Eval(_) | Command::Ingest(_) | Command::TextRecall(_) => {
            bail!("not a client command")
        }
        Command::Insert {
            server,
            file,
            batch,
        } => client::insert(&server, &file, batch).await?,
        Command::Query {
            server,
            file,
            output,
        } => client::query(&server, &file, output).await?,
        Command::Erase {
            server,
            session,
            keyframe_ids,
        } => client::erase(&server, session, keyframe_ids).await?,
        Command::ResetMap {
            server,
            session,
            map,
        } => client::reset_map(&server, session, map).await?,
        Command::ResetSession { server, session } => {
            client::reset_session(&server, session).await?
        }
        Command::Stats { server } => client::stats(&server).await?,
    }
    Ok(())
}
