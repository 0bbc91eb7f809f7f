//! The command line: `humem serve` and the client commands.
//!
//! The client reads and prints the API's messages in the proto3 JSON mapping
//! (field names in lowerCamelCase, 64-bit ids as strings or numbers), so what
//! a script sends is exactly what the `.proto` documents.

pub(crate) mod client;
#[cfg(feature = "eval")]
pub mod cluster_bench;
pub mod export;
pub mod load;
pub mod models;
pub mod probe;
pub mod token;

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use figment::providers::Serialized;
use figment::Figment;

pub use client::run_client;

use humem_server::config::LogFormat;

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

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Output {
    Json,
    Table,
}

/// Flags of `humem serve`; each overrides the configuration setting it names.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// gRPC listen address (server.listen).
    #[arg(long)]
    pub listen: Option<SocketAddr>,
    /// Data directory of the store (store.data_dir).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Log format (log.format).
    #[arg(long)]
    pub log_format: Option<LogFormat>,
}

impl ServeArgs {
    /// The flags as the top configuration layer.
    pub fn overrides(&self) -> Figment {
        let mut figment = Figment::new();
        if let Some(listen) = self.listen {
            figment = figment.merge(Serialized::default("server.listen", listen));
        }
        if let Some(dir) = &self.data_dir {
            figment = figment.merge(Serialized::default("store.data_dir", dir));
        }
        if let Some(format) = self.log_format {
            figment = figment.merge(Serialized::default("log.format", format));
        }
        figment
    }
}

/// Address of the server a client command talks to.
#[derive(Debug, Args)]
pub struct ServerArg {
    /// Server URL.
    #[arg(
        long,
        env = "HUMEM_SERVER_URL",
        default_value = "http://127.0.0.1:50051"
    )]
    pub server: String,
    #[command(flatten)]
    pub tls: humem_server::client::ClientCredentials,
}

/// Robot and session of a maintenance command.
#[derive(Debug, Args)]
pub struct SessionArgs {
    #[arg(long)]
    pub robot: String,
    #[arg(long, default_value = "")]
    pub session: String,
}
