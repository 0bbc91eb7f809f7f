//! The `humem` command: the service (`humem serve`) and a command-line client
//! for people and scripts (`humem insert`, `humem query`, ...), and with the
//! `eval` feature (on by default) the evaluation and benchmarks (`humem eval`,
//! `humem bench`, `humem text-recall`).
//!
//! - [`cli`]: the command line (clap) and the client commands, including the
//!   load generator and the store export.

mod cli;
#[cfg(test)]
mod docs_examples;

use std::io::IsTerminal;

use clap::Parser;

#[cfg(feature = "eval")]
use crate::cli::BenchCommand;
use crate::cli::{Cli, Command};
use humem_server::config::{Config, LogFormat};

fn init_logging(format: LogFormat, filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(filter));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    match format {
        LogFormat::Plain => builder.init(),
        LogFormat::Json => builder.json().init(),
    }
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Serve(args) => {
            let config = Config::load(cli.config.as_deref(), args.overrides())?;
            init_logging(config.log.format, &config.log.filter);
            // The access rules follow the configuration file while serving.
            let rules_file = cli.config.clone().map(|file| {
                let overrides = args.overrides();
                let path = file.clone();
                let reread: humem_server::auth::RulesSource = Box::new(move || {
                    Config::load(Some(&path), overrides.clone())
                        .map(|c| humem_server::auth::AccessRules::of(&c.auth))
                        .map_err(|e| e.to_string())
                });
                (file, reread)
            });
            humem_server::server::serve_watching(config, rules_file).await
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Perception(args)) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem_eval::perception_bench::perception(config, args).await
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Graph(args)) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn");
            humem_eval::graph_bench::graph(config, args)
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Scan(args)) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn");
            humem_eval::scan_bench::scan(config, args)
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Restart(args)) => {
            init_logging(LogFormat::Plain, "warn");
            humem_eval::restart_bench::restart(args).await
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Verdicts(args)) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn");
            humem_eval::verdict_bench::verdicts(config, args)
        }
        #[cfg(feature = "eval")]
        Command::Bench(BenchCommand::Cluster(args)) => {
            init_logging(LogFormat::Plain, "warn");
            cli::cluster_bench::run(args).await
        }
        #[cfg(feature = "eval")]
        Command::Eval(args) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem_eval::run::run(config, args).await
        }
        #[cfg(feature = "eval")]
        Command::Ingest(args) => {
            init_logging(LogFormat::Plain, "warn");
            humem_eval::ingest::run(args).await
        }
        #[cfg(feature = "eval")]
        Command::TextRecall(args) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem_eval::text_recall::run(config, args).await
        }
        Command::Probe { url } => crate::cli::probe::run(&url).await,
        Command::Token(command) => {
            init_logging(LogFormat::Plain, "warn");
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            crate::cli::token::run(command, config.auth.tokens_file.as_deref())
        }
        Command::Models(command) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            // ONNX Runtime's errors are in the check's own messages.
            init_logging(LogFormat::Plain, "warn,ort::logging=off");
            crate::cli::models::run(command, &config)
        }
        Command::Export { data_dir } => {
            init_logging(LogFormat::Plain, "warn");
            let count = crate::cli::export::export(&data_dir, &mut std::io::stdout().lock())?;
            eprintln!("humem export: {count} keyframes");
            Ok(())
        }
        command => {
            init_logging(LogFormat::Plain, "warn");
            crate::cli::run_client(command).await
        }
    }
}
