//! Connecting to a HuMem server as a client: the one place that knows the
//! channel settings every client of this workspace uses (the command line,
//! `humem load`, `humem eval --server`), so they cannot drift apart.
//!
//! An `https://` URL connects over TLS, trusting the CA given with
//! `--tls-ca` (or the system's roots without one), and presenting a client
//! certificate when `--tls-cert` and `--tls-key` are given (mutual TLS).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Identity};

use crate::proto::place_recognition_client::PlaceRecognitionClient;

/// Largest message a client sends or accepts (the server's default limit).
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// How a client authenticates the server, and itself, over TLS.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ClientTls {
    /// PEM CA bundle the server's certificate must chain to (an `https://`
    /// URL without it trusts the system's roots).
    #[arg(long, env = "HUMEM_TLS_CA", value_name = "PEM")]
    pub tls_ca: Option<PathBuf>,
    /// PEM client certificate chain, for servers that require mutual TLS.
    #[arg(long, env = "HUMEM_TLS_CERT", value_name = "PEM", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of `--tls-cert`.
    #[arg(long, env = "HUMEM_TLS_KEY", value_name = "PEM", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Name to check the server's certificate against, when it differs from
    /// the URL's host (e.g. connecting by IP address).
    #[arg(long, env = "HUMEM_TLS_SERVER_NAME", value_name = "NAME")]
    pub tls_server_name: Option<String>,
}

impl ClientTls {
    fn is_set(&self) -> bool {
        self.tls_ca.is_some() || self.tls_cert.is_some() || self.tls_server_name.is_some()
    }

    fn config(&self) -> anyhow::Result<ClientTlsConfig> {
        let read = |path: &Path| {
            std::fs::read(path).with_context(|| format!("reading {}", path.display()))
        };
        let mut config = ClientTlsConfig::new();
        config = match &self.tls_ca {
            Some(ca) => config.ca_certificate(Certificate::from_pem(read(ca)?)),
            None => config.with_native_roots(),
        };
        if let (Some(cert), Some(key)) = (&self.tls_cert, &self.tls_key) {
            config = config.identity(Identity::from_pem(read(cert)?, read(key)?));
        }
        if let Some(name) = &self.tls_server_name {
            config = config.domain_name(name);
        }
        Ok(config)
    }
}

/// A channel to the server at `url` (`http://HOST:PORT` or
/// `https://HOST:PORT`).
pub async fn channel(url: &str, tls: &ClientTls) -> anyhow::Result<Channel> {
    let mut endpoint = Channel::from_shared(url.to_string())
        .with_context(|| format!("invalid server URL {url:?}"))?;
    if url.starts_with("https://") {
        endpoint = endpoint
            .tls_config(tls.config()?)
            .context("setting up TLS")?;
    } else if tls.is_set() {
        bail!("TLS options are given but {url} is not an https:// URL");
    }
    endpoint
        .connect()
        .await
        .with_context(|| format!("connecting to {url}"))
}

/// Connects to the server at `url`.
pub async fn connect(
    url: &str,
    tls: &ClientTls,
) -> anyhow::Result<PlaceRecognitionClient<Channel>> {
    Ok(PlaceRecognitionClient::new(channel(url, tls).await?)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES))
}
