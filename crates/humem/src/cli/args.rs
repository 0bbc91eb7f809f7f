//! The flag groups the commands share: `humem serve`'s overrides, the
//! server a client command talks to, a maintenance command's robot and
//! session, and how answers are printed.
//!
//! Kept apart from the command enum (the parent module) so that the client
//! commands ([`super::client`]) can take them without using their parent.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;
use figment::providers::Serialized;
use figment::Figment;

use humem_server::config::LogFormat;

// How `humem query` prints its answers (no doc comment: clap would show it).
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
#[derive(Debug, Clone, Args)]
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
