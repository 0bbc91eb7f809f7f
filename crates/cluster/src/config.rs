//! Cluster-mode settings (`[cluster]` in the server's configuration): where
//! NATS is, how the stream is made, how long a write and a read may wait,
//! and the NATS credentials and TLS.
//!
//! Plain data with serde defaults, checked by [`ClusterConfig::validate`],
//! so the server embeds it in its own configuration and every setting has
//! one name in TOML, `HUMEM_CLUSTER__*` variables and flags.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Cluster mode. Off by default: the server keeps its writes to itself, as
/// the vehicle sidecar does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClusterConfig {
    /// Publish every write to the stream and apply the stream in order.
    pub enabled: bool,
    /// NATS servers to connect to (any of the cluster's; the client learns
    /// the rest), e.g. `nats://nats-0.nats:4222` or `tls://…`.
    pub nats_urls: Vec<String>,
    /// This replica's name, in NATS connection names and logs (empty: the
    /// host name).
    pub replica_name: String,
    /// The JetStream stream holding the write log.
    pub stream: String,
    /// The subject writes are published on (the stream's only subject).
    pub subject: String,
    /// Copies of the stream JetStream keeps, on different NATS servers (3
    /// survives one server lost; 1 for a single NATS server).
    pub stream_replicas: usize,
    /// Hours an entry is kept in the stream (0: for ever; default a day).
    /// A replica away longer than this starts from the newest store
    /// snapshot instead (`snapshot_every`; docs/fleet-and-cluster.md,
    /// "Retention").
    pub max_age_hours: u64,
    /// Log entries a replica applies between store snapshots it publishes
    /// to the bucket `<stream>_SNAPSHOTS` (any replica's snapshot counts);
    /// a replica whose next entry has aged out of the stream starts from
    /// the newest one. 0: this replica publishes none.
    pub snapshot_every: u64,
    /// Seconds within which a write published again (a retry after a lost
    /// acknowledgement) is recognised by its id and stored once.
    pub duplicate_window_s: u64,
    /// Longest a write keeps trying to reach JetStream before it fails
    /// with UNAVAILABLE, in milliseconds.
    pub publish_timeout_ms: u64,
    /// Longest a write waits, once in the log, for this replica to apply it
    /// (its answer carries the outcome), in milliseconds.
    pub apply_timeout_ms: u64,
    /// Longest a query asking for a log position waits for this replica to
    /// reach it, in milliseconds (less if its gRPC deadline is sooner).
    pub max_read_wait_ms: u64,
    /// Whether a replica whose applier halted (an entry from a newer build,
    /// entries removed before it applied them) still answers queries from
    /// its store, which no longer follows the log. Off by default: such a
    /// replica refuses queries with UNAVAILABLE and the reason, so a client
    /// that ignores readiness is not answered from a stale store.
    pub serve_stale_reads: bool,
    /// NATS credentials (`[cluster.auth]`).
    pub auth: NatsAuth,
    /// TLS to NATS (`[cluster.tls]`).
    pub tls: NatsTls,
}

impl Default for ClusterConfig {
    fn default() -> Self {
        ClusterConfig {
            enabled: false,
            nats_urls: vec!["nats://127.0.0.1:4222".into()],
            replica_name: String::new(),
            stream: "HUMEM_WRITES".into(),
            subject: "humem.writes".into(),
            stream_replicas: 3,
            max_age_hours: 24,
            snapshot_every: 100_000,
            duplicate_window_s: 120,
            publish_timeout_ms: 10_000,
            apply_timeout_ms: 10_000,
            max_read_wait_ms: 5_000,
            serve_stale_reads: false,
            auth: NatsAuth::default(),
            tls: NatsTls::default(),
        }
    }
}

/// How this replica proves itself to NATS: at most one of a token, a user
/// with a password, or a credentials (JWT + NKey) file. Secrets are read
/// from files, never from the configuration itself.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NatsAuth {
    /// A file holding the token.
    pub token_file: Option<PathBuf>,
    /// A user name; needs `password_file`.
    pub user: Option<String>,
    /// A file holding the user's password.
    pub password_file: Option<PathBuf>,
    /// A `.creds` file (decentralised JWT authentication).
    pub credentials_file: Option<PathBuf>,
}

/// TLS to the NATS servers. `ca` set: the servers must present a
/// certificate from it; `cert` and `key` set: this replica presents its
/// own (mutual TLS).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NatsTls {
    /// PEM bundle of the CAs the NATS servers' certificates chain to.
    pub ca: Option<PathBuf>,
    /// PEM client certificate.
    pub cert: Option<PathBuf>,
    /// PEM private key of `cert`.
    pub key: Option<PathBuf>,
}

impl NatsTls {
    /// Whether TLS to NATS is configured.
    pub fn enabled(&self) -> bool {
        self.ca.is_some() || self.cert.is_some()
    }
}

impl NatsAuth {
    /// Whether any credential is configured.
    pub fn enabled(&self) -> bool {
        self.token_file.is_some() || self.user.is_some() || self.credentials_file.is_some()
    }
}

impl ClusterConfig {
    /// Checks the settings (not the files); the message names the setting.
    pub fn validate(&self) -> Result<(), String> {
        if !self.enabled {
            return Ok(());
        }
        if self.nats_urls.is_empty() {
            return Err("cluster.nats_urls must name at least one NATS server".into());
        }
        for url in &self.nats_urls {
            url.parse::<async_nats::ServerAddr>()
                .map_err(|e| format!("cluster.nats_urls: {url:?} is not a NATS URL: {e}"))?;
        }
        let token = |s: &str| {
            !s.is_empty()
                && s.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        };
        if !token(&self.stream) {
            return Err(format!(
                "cluster.stream {:?} must be letters, digits, '-' or '_'",
                self.stream
            ));
        }
        if self.subject.split('.').any(|part| !token(part)) {
            return Err(format!(
                "cluster.subject {:?} must be dot-separated tokens of letters, digits, '-' or '_' (no wildcards)",
                self.subject
            ));
        }
        if !(1..=5).contains(&self.stream_replicas) {
            return Err(
                "cluster.stream_replicas must be between 1 and 5 (JetStream's limit)".into(),
            );
        }
        for (name, value) in [
            ("duplicate_window_s", self.duplicate_window_s),
            ("publish_timeout_ms", self.publish_timeout_ms),
            ("apply_timeout_ms", self.apply_timeout_ms),
        ] {
            if value == 0 {
                return Err(format!("cluster.{name} must be at least 1"));
            }
        }
        let auth = &self.auth;
        let ways = [
            auth.token_file.is_some(),
            auth.user.is_some(),
            auth.credentials_file.is_some(),
        ];
        if ways.iter().filter(|&&w| w).count() > 1 {
            return Err("cluster.auth: set only one of token_file, user (with password_file) and credentials_file".into());
        }
        if auth.user.is_some() != auth.password_file.is_some() {
            return Err("cluster.auth.user and cluster.auth.password_file go together".into());
        }
        if self.tls.cert.is_some() != self.tls.key.is_some() {
            return Err("cluster.tls.cert and cluster.tls.key go together".into());
        }
        Ok(())
    }

    /// `publish_timeout_ms` as a duration.
    pub fn publish_timeout(&self) -> Duration {
        Duration::from_millis(self.publish_timeout_ms)
    }

    /// `apply_timeout_ms` as a duration.
    pub fn apply_timeout(&self) -> Duration {
        Duration::from_millis(self.apply_timeout_ms)
    }

    /// `max_read_wait_ms` as a duration.
    pub fn max_read_wait(&self) -> Duration {
        Duration::from_millis(self.max_read_wait_ms)
    }

    /// Whether every NATS URL is on this machine (loopback), where no one
    /// else can listen in.
    pub fn nats_is_local(&self) -> bool {
        self.nats_urls.iter().all(|url| {
            url.parse::<async_nats::ServerAddr>()
                .is_ok_and(|addr| matches!(addr.host(), "localhost" | "127.0.0.1" | "::1"))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enabled() -> ClusterConfig {
        ClusterConfig {
            enabled: true,
            ..ClusterConfig::default()
        }
    }

    #[test]
    fn defaults_are_valid_and_off() {
        assert!(!ClusterConfig::default().enabled);
        enabled().validate().unwrap();
        assert!(enabled().nats_is_local());
    }

    #[test]
    fn bad_settings_name_the_setting() {
        for (config, field) in [
            (
                ClusterConfig {
                    nats_urls: vec![],
                    ..enabled()
                },
                "nats_urls",
            ),
            (
                ClusterConfig {
                    nats_urls: vec!["nats://host:port".into()],
                    ..enabled()
                },
                "nats_urls",
            ),
            (
                ClusterConfig {
                    subject: "humem.*".into(),
                    ..enabled()
                },
                "subject",
            ),
            (
                ClusterConfig {
                    stream: "a.b".into(),
                    ..enabled()
                },
                "stream",
            ),
            (
                ClusterConfig {
                    stream_replicas: 0,
                    ..enabled()
                },
                "stream_replicas",
            ),
            (
                ClusterConfig {
                    publish_timeout_ms: 0,
                    ..enabled()
                },
                "publish_timeout_ms",
            ),
            (
                ClusterConfig {
                    auth: NatsAuth {
                        user: Some("humem".into()),
                        ..NatsAuth::default()
                    },
                    ..enabled()
                },
                "password_file",
            ),
            (
                ClusterConfig {
                    auth: NatsAuth {
                        token_file: Some("t".into()),
                        credentials_file: Some("c".into()),
                        ..NatsAuth::default()
                    },
                    ..enabled()
                },
                "only one",
            ),
            (
                ClusterConfig {
                    tls: NatsTls {
                        cert: Some("c".into()),
                        ..NatsTls::default()
                    },
                    ..enabled()
                },
                "cluster.tls.cert",
            ),
        ] {
            let err = config.validate().unwrap_err();
            assert!(err.contains(field), "{field}: {err}");
        }
    }

    #[test]
    fn only_loopback_urls_are_local() {
        let with = |urls: &[&str]| ClusterConfig {
            nats_urls: urls.iter().map(|u| u.to_string()).collect(),
            ..enabled()
        };
        assert!(with(&[
            "nats://127.0.0.1:4222",
            "localhost:4223",
            "nats://u:p@[::1]:4222"
        ])
        .nats_is_local());
        assert!(!with(&["nats://127.0.0.1:4222", "nats://nats-1.nats:4222"]).nats_is_local());
    }
}
