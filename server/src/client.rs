//! Connecting to a HuMem server as a client: the one place that knows the
//! channel settings every client of this workspace uses (the command line,
//! `humem load`, `humem eval --server`), so they cannot drift apart.
//!
//! An `https://` URL connects over TLS, trusting the CA given with
//! `--tls-ca` (or the system's roots without one), and presenting a client
//! certificate when `--tls-cert` and `--tls-key` are given (mutual TLS).
//! `--token` sends a bearer token with every call; only over TLS, so that
//! it never crosses the network in the clear.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use tonic::metadata::MetadataValue;
use tonic::service::interceptor::InterceptedService;
use tonic::service::Interceptor;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Identity};

use crate::proto::place_recognition_client::PlaceRecognitionClient;

/// Largest message a client sends or accepts (the server's default limit).
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// How a client checks the server and proves who it is: TLS options and
/// a bearer token.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ClientCredentials {
    /// Bearer token from `humem token add`, sent with every call (needs an
    /// `https://` URL).
    #[arg(
        long,
        env = "HUMEM_TOKEN",
        value_name = "TOKEN",
        hide_env_values = true
    )]
    pub token: Option<String>,
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

impl ClientCredentials {
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

/// Adds `authorization: Bearer <token>` to every call, when there is a
/// token.
#[derive(Clone)]
pub struct BearerToken(Option<MetadataValue<tonic::metadata::Ascii>>);

impl Interceptor for BearerToken {
    fn call(
        &mut self,
        mut request: tonic::Request<()>,
    ) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(value) = &self.0 {
            request
                .metadata_mut()
                .insert("authorization", value.clone());
        }
        Ok(request)
    }
}

/// A connection to a server: the channel, and the token its calls carry.
pub type Connection = InterceptedService<Channel, BearerToken>;

/// A connection to the server at `url` (`http://HOST:PORT` or
/// `https://HOST:PORT`).
pub async fn channel(url: &str, tls: &ClientCredentials) -> anyhow::Result<Connection> {
    let token = match &tls.token {
        None => None,
        Some(_) if !url.starts_with("https://") => {
            bail!("a token is only sent over TLS, and {url} is not an https:// URL")
        }
        Some(token) => {
            let mut value: MetadataValue<_> = format!("Bearer {token}")
                .parse()
                .context("the token is not valid header text")?;
            value.set_sensitive(true);
            Some(value)
        }
    };
    Ok(InterceptedService::new(
        raw_channel(url, tls).await?,
        BearerToken(token),
    ))
}

async fn raw_channel(url: &str, tls: &ClientCredentials) -> anyhow::Result<Channel> {
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
    tls: &ClientCredentials,
) -> anyhow::Result<PlaceRecognitionClient<Connection>> {
    Ok(PlaceRecognitionClient::new(channel(url, tls).await?)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES))
}
