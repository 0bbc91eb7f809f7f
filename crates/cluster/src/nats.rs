//! The NATS side: connecting with this replica's credentials and TLS, and
//! making sure the write stream exists with the configured shape.
//!
//! Both retry for a while at start, since in a cluster the NATS servers
//! and the replicas start in any order, and a new NATS cluster needs a few
//! seconds to elect its JetStream leader.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_nats::jetstream::{self, stream};
use async_nats::{Client, ConnectOptions, Event};

use crate::config::ClusterConfig;
use crate::error::ClusterError;
use crate::observe::ClusterObserver;

/// How long the start keeps trying to reach NATS and its stream.
const START_PATIENCE: Duration = Duration::from_secs(60);

/// Each attempt's wait for JetStream's answer (a publish is retried with
/// the same id until `publish_timeout_ms`).
pub(crate) const ATTEMPT_TIMEOUT: Duration = Duration::from_secs(2);

/// This replica's name: configured, or the host's.
pub(crate) fn replica_name(config: &ClusterConfig) -> String {
    if !config.replica_name.is_empty() {
        return config.replica_name.clone();
    }
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "humem".into())
}

fn read_secret(setting: &str, path: &std::path::Path) -> Result<String, ClusterError> {
    std::fs::read_to_string(path)
        .map(|s| s.trim().to_string())
        .map_err(|e| ClusterError::Config(format!("{setting} {}: {e}", path.display())))
}

/// Connection options from the settings: name, credentials, TLS, and
/// reconnects for ever (the client reconnects to any server it knows).
async fn options(
    config: &ClusterConfig,
    observer: Arc<dyn ClusterObserver>,
) -> Result<ConnectOptions, ClusterError> {
    let mut options = ConnectOptions::new()
        .name(format!("humem-{}", replica_name(config)))
        .connection_timeout(Duration::from_secs(5))
        .max_reconnects(None)
        .event_callback(move |event| {
            let observer = observer.clone();
            async move {
                match event {
                    Event::Connected => {
                        tracing::info!("connected to NATS");
                        observer.connected(true);
                    }
                    Event::Disconnected => {
                        tracing::warn!("disconnected from NATS: reconnecting");
                        observer.connected(false);
                    }
                    other => tracing::debug!(event = %other, "NATS"),
                }
            }
        });
    let auth = &config.auth;
    if let Some(path) = &auth.token_file {
        options = options.token(read_secret("cluster.auth.token_file", path)?);
    }
    if let (Some(user), Some(path)) = (&auth.user, &auth.password_file) {
        options = options.user_and_password(
            user.clone(),
            read_secret("cluster.auth.password_file", path)?,
        );
    }
    if let Some(path) = &auth.credentials_file {
        options = options.credentials_file(path).await.map_err(|e| {
            ClusterError::Config(format!(
                "cluster.auth.credentials_file {}: {e}",
                path.display()
            ))
        })?;
    }
    let tls = &config.tls;
    if tls.enabled() {
        options = options.require_tls(true);
    }
    if let Some(ca) = &tls.ca {
        options = options.add_root_certificates(ca.clone());
    }
    if let (Some(cert), Some(key)) = (&tls.cert, &tls.key) {
        options = options.add_client_certificate(cert.clone(), key.clone());
    }
    Ok(options)
}

/// Connects to NATS, trying again for up to a minute.
pub(crate) async fn connect(
    config: &ClusterConfig,
    observer: Arc<dyn ClusterObserver>,
) -> Result<Client, ClusterError> {
    let started = Instant::now();
    // One address per URL: a comma-joined list is not parsed as several.
    let servers = config
        .nats_urls
        .iter()
        .map(|url| {
            url.parse::<async_nats::ServerAddr>()
                .map_err(|e| ClusterError::Config(format!("cluster.nats_urls: {url:?}: {e}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let urls = config.nats_urls.join(",");
    loop {
        match options(config, observer.clone())
            .await?
            .connect(servers.clone())
            .await
        {
            Ok(client) => {
                observer.connected(true);
                return Ok(client);
            }
            // Wrong credentials or certificates do not get better by
            // waiting: say so at once.
            Err(e) if refused(&e) => {
                return Err(ClusterError::Nats(format!(
                    "connecting to {urls} (cluster.nats_urls) was refused: {e} (check cluster.auth and cluster.tls)"
                )))
            }
            Err(e) if started.elapsed() < START_PATIENCE => {
                tracing::warn!(%urls, error = %e, "cannot reach NATS yet; retrying");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
            Err(e) => {
                return Err(ClusterError::Nats(format!(
                    "connecting to {urls} (cluster.nats_urls): {e}"
                )))
            }
        }
    }
}

/// Whether NATS refused this replica (credentials, TLS) rather than not
/// answering.
fn refused(e: &async_nats::ConnectError) -> bool {
    use async_nats::ConnectErrorKind::*;
    match e.kind() {
        Authentication | AuthorizationViolation | Tls | ServerParse => true,
        // A TLS handshake that fails (an untrusted certificate) surfaces as
        // an I/O error of invalid data; a server not up yet does not.
        Io => std::error::Error::source(e)
            .and_then(|s| s.downcast_ref::<std::io::Error>())
            .is_some_and(|io| io.kind() == std::io::ErrorKind::InvalidData),
        _ => false,
    }
}

/// The stream's configuration from the settings.
fn stream_config(config: &ClusterConfig) -> stream::Config {
    stream::Config {
        name: config.stream.clone(),
        subjects: vec![config.subject.clone()],
        storage: stream::StorageType::File,
        num_replicas: config.stream_replicas,
        retention: stream::RetentionPolicy::Limits,
        discard: stream::DiscardPolicy::Old,
        max_age: Duration::from_secs(config.max_age_hours.saturating_mul(3600)),
        duplicate_window: Duration::from_secs(config.duplicate_window_s),
        ..Default::default()
    }
}

/// The write stream, created when missing. An existing stream is used as
/// it is; where its replicas or retention differ from the settings, that
/// is logged (changing a live stream is an operator's decision).
pub(crate) async fn stream(
    js: &jetstream::Context,
    config: &ClusterConfig,
) -> Result<stream::Stream, ClusterError> {
    let wanted = stream_config(config);
    let started = Instant::now();
    loop {
        match js.get_or_create_stream(wanted.clone()).await {
            Ok(mut stream) => {
                let info = stream
                    .info()
                    .await
                    .map_err(|e| ClusterError::Nats(format!("stream {}: {e}", config.stream)))?;
                let have = &info.config;
                if have.num_replicas != wanted.num_replicas
                    || have.max_age != wanted.max_age
                    || have.subjects != wanted.subjects
                {
                    tracing::warn!(
                        stream = %config.stream,
                        replicas = have.num_replicas,
                        max_age = ?have.max_age,
                        subjects = ?have.subjects,
                        "the stream exists with other settings than cluster.*; using it as it is"
                    );
                }
                return Ok(stream);
            }
            Err(e) if started.elapsed() < START_PATIENCE => {
                tracing::warn!(stream = %config.stream, error = %e, "JetStream not ready; retrying");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
            Err(e) => {
                return Err(ClusterError::Nats(format!(
                    "creating stream {} with {} replicas (cluster.stream_replicas): {e}",
                    config.stream, config.stream_replicas
                )))
            }
        }
    }
}
