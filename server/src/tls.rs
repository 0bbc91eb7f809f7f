//! TLS on the gRPC port: rustls, with the certificate chain, its key and
//! (for mutual TLS) the client CA read from PEM files and reloaded when any
//! of them changes, so a certificate rotation needs no restart.
//!
//! Shaped as an accept loop of our own rather than tonic's
//! `ServerTlsConfig`, which fixes its certificate at start: each accepted
//! connection is handshaken with the configuration current at that moment
//! (a connection keeps the one it started with), on its own task with a
//! deadline, so a slow or hostile client holds up no one else. A reload
//! that fails (a half-written file, a key that does not match) is logged
//! and counted, and the previous configuration stays in use.

use std::io;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, RwLock};
use std::task::{Context, Poll};
use std::time::Duration;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::server::WebPkiClientVerifier;
use rustls::{RootCertStore, ServerConfig};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio_rustls::server::TlsStream;
use tokio_rustls::TlsAcceptor;
use tokio_stream::Stream;

use crate::config::{ClientAuth, TlsSettings};
use crate::metrics;

/// Longest a client may take to complete its handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// Handshaken connections waiting for the gRPC server to take them.
const ACCEPTED_BACKLOG: usize = 128;

/// Why a TLS configuration could not be built; the message names the file.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// A file could not be read or holds no usable PEM item.
    #[error("{path}: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// What was wrong with it.
        reason: String,
    },
    /// rustls refused the combination (e.g. a key that does not match the
    /// certificate).
    #[error("TLS configuration: {0}")]
    Rustls(String),
}

fn file_error(path: &Path, reason: impl ToString) -> TlsError {
    TlsError::File {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

fn read_certificates(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let certificates = CertificateDer::pem_file_iter(path)
        .map_err(|e| file_error(path, e))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| file_error(path, e))?;
    if certificates.is_empty() {
        return Err(file_error(path, "no PEM certificate in it"));
    }
    Ok(certificates)
}

/// Builds the rustls configuration from the files named in `settings`.
pub fn build_config(settings: &TlsSettings) -> Result<Arc<ServerConfig>, TlsError> {
    let (Some(cert), Some(key)) = (&settings.cert, &settings.key) else {
        return Err(TlsError::Rustls("no certificate and key configured".into()));
    };
    let chain = read_certificates(cert)?;
    let key = PrivateKeyDer::from_pem_file(key).map_err(|e| file_error(key, e))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ServerConfig::builder_with_provider(provider.clone())
        .with_safe_default_protocol_versions()
        .map_err(|e| TlsError::Rustls(e.to_string()))?;
    let builder = match &settings.client_ca {
        Some(ca) => {
            let mut roots = RootCertStore::empty();
            for certificate in read_certificates(ca)? {
                roots.add(certificate).map_err(|e| file_error(ca, e))?;
            }
            let verifier = WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider);
            let verifier = match settings.client_auth {
                ClientAuth::Required => verifier,
                ClientAuth::Optional => verifier.allow_unauthenticated(),
            }
            .build()
            .map_err(|e| file_error(ca, e))?;
            builder.with_client_cert_verifier(verifier)
        }
        None => builder.with_no_client_auth(),
    };
    let mut config = builder
        .with_single_cert(chain, key)
        .map_err(|e| TlsError::Rustls(e.to_string()))?;
    // gRPC is HTTP/2 only.
    config.alpn_protocols = vec![b"h2".to_vec()];
    Ok(Arc::new(config))
}

/// The server's TLS configuration, swapped whole when its files change.
#[derive(Clone)]
pub struct ReloadingTls {
    current: Arc<RwLock<Arc<ServerConfig>>>,
}

impl ReloadingTls {
    /// Builds the configuration once (an error here stops the start) and
    /// starts the task that rebuilds it when a file changes.
    pub fn start(settings: TlsSettings) -> Result<ReloadingTls, TlsError> {
        let files: Vec<_> = settings
            .files()
            .into_iter()
            .map(Path::to_path_buf)
            .collect();
        let seen = crate::watch::Snapshot::of(&files);
        let config = build_config(&settings)?;
        let tls = ReloadingTls {
            current: Arc::new(RwLock::new(config)),
        };
        let watched = tls.clone();
        crate::watch::on_change(files, seen, move || watched.reload(&settings));
        Ok(tls)
    }

    fn current(&self) -> Arc<ServerConfig> {
        self.current
            .read()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .clone()
    }

    /// Rebuilds the configuration after its files changed; `false` once the
    /// server is gone (only the watcher's clone is left).
    fn reload(&self, settings: &TlsSettings) -> bool {
        if Arc::strong_count(&self.current) == 1 {
            return false;
        }
        match build_config(settings) {
            Ok(config) => {
                *self
                    .current
                    .write()
                    .unwrap_or_else(|poisoned| poisoned.into_inner()) = config;
                metrics::TLS_RELOADS.with_label_values(&["ok"]).inc();
                tracing::info!("TLS certificate files changed: reloaded");
            }
            Err(e) => {
                metrics::TLS_RELOADS.with_label_values(&["error"]).inc();
                tracing::warn!(error = %e, "TLS certificate files changed but cannot be loaded; keeping the previous ones");
            }
        }
        true
    }
}

/// Accepted, handshaken TLS connections, for tonic's
/// `serve_with_incoming_shutdown`. Dropping it stops accepting.
pub struct TlsIncoming {
    accepted: tokio::sync::mpsc::Receiver<TlsStream<TcpStream>>,
    acceptor: JoinHandle<()>,
}

impl TlsIncoming {
    /// Accepts on `listener`, handshaking each connection with the
    /// configuration current when it arrives.
    pub fn new(listener: TcpListener, tls: ReloadingTls) -> TlsIncoming {
        let (tx, accepted) = tokio::sync::mpsc::channel(ACCEPTED_BACKLOG);
        let acceptor = tokio::spawn(async move {
            loop {
                let (stream, peer) = match listener.accept().await {
                    Ok(connection) => connection,
                    Err(e) => {
                        // Out of file descriptors and the like: wait, go on.
                        tracing::warn!(error = %e, "accepting a connection failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                if tx.is_closed() {
                    return;
                }
                // See `server`: small answers must not wait for delayed ACKs.
                let _ = stream.set_nodelay(true);
                let acceptor = TlsAcceptor::from(tls.current());
                let tx = tx.clone();
                tokio::spawn(async move {
                    match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(stream)).await {
                        Ok(Ok(stream)) => {
                            let _ = tx.send(stream).await;
                        }
                        Ok(Err(e)) => handshake_failed(peer, &e.to_string()),
                        Err(_) => handshake_failed(peer, "timed out"),
                    }
                });
            }
        });
        TlsIncoming { accepted, acceptor }
    }
}

fn handshake_failed(peer: std::net::SocketAddr, reason: &str) {
    metrics::TLS_HANDSHAKE_FAILURES.inc();
    tracing::info!(%peer, reason, "TLS handshake failed");
}

impl Stream for TlsIncoming {
    type Item = Result<TlsStream<TcpStream>, io::Error>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        self.accepted.poll_recv(cx).map(|stream| stream.map(Ok))
    }
}

impl Drop for TlsIncoming {
    fn drop(&mut self) {
        self.acceptor.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_pair(dir: &Path, name: &str) -> (PathBuf, PathBuf) {
        let cert = rcgen::generate_simple_self_signed(vec!["localhost".into()]).unwrap();
        let cert_path = dir.join(format!("{name}.crt"));
        let key_path = dir.join(format!("{name}.key"));
        std::fs::write(&cert_path, cert.cert.pem()).unwrap();
        std::fs::write(&key_path, cert.signing_key.serialize_pem()).unwrap();
        (cert_path, key_path)
    }

    #[test]
    fn settings_must_come_in_pairs() {
        let path = Some(PathBuf::from("x.pem"));
        let only_cert = TlsSettings {
            cert: path.clone(),
            ..TlsSettings::default()
        };
        assert!(only_cert.validate().unwrap_err().contains("server.tls.key"));
        let only_ca = TlsSettings {
            client_ca: path.clone(),
            ..TlsSettings::default()
        };
        assert!(only_ca.validate().unwrap_err().contains("client_ca"));
        assert!(TlsSettings::default().validate().is_ok());
        assert!(!TlsSettings::default().enabled());
    }

    #[test]
    fn bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let (cert, key) = write_pair(dir.path(), "a");
        let (_, other_key) = write_pair(dir.path(), "b");
        let settings = TlsSettings {
            cert: Some(cert.clone()),
            key: Some(key.clone()),
            ..TlsSettings::default()
        };
        build_config(&settings).unwrap();

        let missing = dir.path().join("missing.crt");
        let err = build_config(&TlsSettings {
            cert: Some(missing.clone()),
            ..settings.clone()
        })
        .unwrap_err();
        assert!(err.to_string().contains("missing.crt"), "{err}");

        // A key file given as the certificate: no certificate in it.
        let err = build_config(&TlsSettings {
            cert: Some(key.clone()),
            ..settings.clone()
        })
        .unwrap_err();
        assert!(err.to_string().contains("no PEM certificate"), "{err}");

        // The other pair's key does not match this certificate.
        let err = build_config(&TlsSettings {
            key: Some(other_key),
            ..settings.clone()
        })
        .unwrap_err();
        assert!(matches!(err, TlsError::Rustls(_)), "{err}");

        // A client CA file with no certificate in it.
        let err = build_config(&TlsSettings {
            client_ca: Some(key),
            ..settings
        })
        .unwrap_err();
        assert!(err.to_string().contains("a.key"), "{err}");
    }
}
