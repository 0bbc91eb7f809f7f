//! The `humem` command: the service (`humem serve`) and a command-line client
//! for people and scripts (`humem insert`, `humem query`, ...).

use std::io::IsTerminal;

use clap::Parser;
use humem::cli::{BenchCommand, Cli, Command};
use humem::config::{Config, LogFormat};

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
            humem::server::serve(config).await
        }
        Command::Bench(BenchCommand::Perception(args)) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem::bench::perception(config, args).await
        }
        Command::Eval(args) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem::eval::run::run(config, args).await
        }
        Command::TextRecall(args) => {
            let config = Config::load(cli.config.as_deref(), figment::Figment::new())?;
            init_logging(LogFormat::Plain, "warn,ort::logging=error");
            humem::eval::text_recall::run(config, args).await
        }
        Command::Export { data_dir } => {
            init_logging(LogFormat::Plain, "warn");
            let count = humem::cli::export::export(&data_dir, &mut std::io::stdout().lock())?;
            eprintln!("humem export: {count} keyframes");
            Ok(())
        }
        command => {
            init_logging(LogFormat::Plain, "warn");
            humem::cli::run_client(command).await
        }
    }
}
