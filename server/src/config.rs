//! Service configuration: defaults that run out of the box, overridden by a
//! TOML file, then by `HUMEM_*` environment variables, then by command-line
//! flags (figment merges the layers, so every setting has one name in all
//! three: `store.data_dir` is `[store] data_dir` in TOML and
//! `HUMEM_STORE__DATA_DIR` in the environment).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use figment::providers::{Env, Format, Serialized, Toml};
use figment::Figment;
use serde::{Deserialize, Serialize};

use humem_core::vpr::params::VprParams;
use humem_perception::config::PerceptionConfig;
use humem_store::FileRule;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// The gRPC endpoint (`[server]`).
    pub server: ServerConfig,
    /// The keyframe store (`[store]`).
    pub store: StoreConfig,
    /// Defaults of query fields a client leaves unset (`[query]`).
    pub query: QueryDefaults,
    /// HuMem-VPR scoring parameters (`[vpr]`), checked at load.
    pub vpr: VprParams,
    /// The perception models (`[perception]`), checked at load.
    pub perception: PerceptionConfig,
    /// The Prometheus endpoint (`[metrics]`).
    pub metrics: MetricsConfig,
    /// Log output (`[log]`).
    pub log: LogConfig,
    /// Who may call, and read which maps (`[auth]`).
    pub auth: AuthConfig,
    /// Per-robot rate and size limits (`[quotas]`).
    pub quotas: QuotaConfig,
    /// Cluster mode: writes through a replicated NATS JetStream log
    /// (`[cluster]`), off by default.
    pub cluster: humem_cluster::ClusterConfig,
}

/// Per-robot limits (`[quotas]`); 0 means no limit.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QuotaConfig {
    /// Keyframes one robot may insert per second (Insert and InsertBatch).
    pub inserts_per_second: u32,
    /// Queries one robot may make per second.
    pub queries_per_second: u32,
    /// Keyframes one robot may hold in the store.
    pub max_keyframes_per_robot: u64,
}

/// Authentication and access rules. Off (every caller may do everything,
/// as on a vehicle's loopback sidecar) unless `tokens_file` is set or the
/// gRPC port requires client certificates (`server.tls.client_ca`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AuthConfig {
    /// The token file `humem token` manages (hashed bearer tokens); read
    /// again within a second of a change.
    pub tokens_file: Option<PathBuf>,
    /// Fleet groups: every robot of a group reads the maps of every other
    /// robot of that group. A robot reads its own maps always, and no one
    /// else's unless a group shares them (admins read everything).
    pub groups: std::collections::BTreeMap<String, Vec<String>>,
    /// Common names of client certificates that act as admins (any other
    /// verified client certificate speaks for the robot its common name
    /// names).
    pub certificate_admins: Vec<String>,
}

/// The Prometheus endpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MetricsConfig {
    /// Serve `/metrics` over HTTP.
    pub enabled: bool,
    /// Its address (9464 is the usual exporter port; Prometheus itself
    /// takes 9090).
    pub listen: SocketAddr,
}

impl Default for MetricsConfig {
    fn default() -> Self {
        MetricsConfig {
            enabled: true,
            listen: SocketAddr::from(([127, 0, 0, 1], 9464)),
        }
    }
}

/// The gRPC endpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServerConfig {
    /// Address the gRPC server listens on.
    pub listen: SocketAddr,
    /// Largest request or response message, in bytes.
    pub max_message_bytes: usize,
    /// TLS on the gRPC port (`[server.tls]`), off unless a certificate and
    /// key are set.
    pub tls: TlsSettings,
    /// Serve a non-loopback address without TLS or without credentials.
    /// Off, such a start is refused: anyone who reaches the port could
    /// write, read and wipe every robot's maps. Turn on only behind
    /// something that does both (a TLS-terminating, authenticating proxy).
    pub allow_insecure_network: bool,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            listen: SocketAddr::from(([127, 0, 0, 1], 50051)),
            max_message_bytes: 16 * 1024 * 1024,
            tls: TlsSettings::default(),
            allow_insecure_network: false,
        }
    }
}

/// TLS settings of the gRPC port (`[server.tls]`). Off unless `cert` and
/// `key` are set.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TlsSettings {
    /// PEM certificate chain the server presents, leaf first.
    pub cert: Option<PathBuf>,
    /// PEM private key of that certificate (PKCS#8, PKCS#1 or SEC1).
    pub key: Option<PathBuf>,
    /// PEM bundle of the CAs client certificates must chain to: set, the
    /// server asks every client for a certificate (mutual TLS).
    pub client_ca: Option<PathBuf>,
    /// With `client_ca`: `required` refuses clients without a valid
    /// certificate; `optional` verifies one when presented.
    pub client_auth: ClientAuth,
}

/// Whether a client certificate is required under mutual TLS.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClientAuth {
    /// Every client must present a certificate from `client_ca`.
    #[default]
    Required,
    /// A certificate is checked when a client presents one.
    Optional,
}

impl TlsSettings {
    /// Whether TLS is configured.
    pub fn enabled(&self) -> bool {
        self.cert.is_some() || self.key.is_some()
    }

    /// Checks that the settings make sense together (not the files).
    pub fn validate(&self) -> Result<(), String> {
        match (&self.cert, &self.key) {
            (Some(_), None) => Err("server.tls.cert is set but server.tls.key is not".into()),
            (None, Some(_)) => Err("server.tls.key is set but server.tls.cert is not".into()),
            (None, None) if self.client_ca.is_some() => {
                Err("server.tls.client_ca needs server.tls.cert and server.tls.key".into())
            }
            _ => Ok(()),
        }
    }

    /// The files the settings name, to watch for changes.
    pub fn files(&self) -> Vec<&Path> {
        [&self.cert, &self.key, &self.client_ca]
            .into_iter()
            .flatten()
            .map(PathBuf::as_path)
            .collect()
    }
}

/// The keyframe store.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StoreConfig {
    /// Directory of the sled database.
    pub data_dir: PathBuf,
    /// Descriptor length; 0 takes it from the first keyframe stored.
    pub descriptor_dim: usize,
    /// Changes waiting for the writer before inserts are pushed back.
    pub write_queue: usize,
    /// Scene classes kept per keyframe (the most probable ones).
    pub scene_top_k: usize,
    /// Keyframe changes between index snapshots (0: only at shutdown). A
    /// restart replays at most about this many changes from the journal.
    pub snapshot_every: u64,
    /// Free bytes kept on the store's disk: inserts, pose updates and
    /// snapshots that would go below are refused with RESOURCE_EXHAUSTED
    /// (erasing still works); 0: no reserve. sled does not survive running
    /// out of space, so keep this above a few `server.max_message_bytes`.
    pub min_free_bytes: u64,
    /// Where the f32 descriptors live (their one-byte codes are always in
    /// memory).
    pub descriptors: DescriptorStorage,
    /// Bytes of sled's page cache.
    pub cache_bytes: u64,
    /// Keep a neighbour graph (HNSW) over the descriptors, saved beside
    /// the index snapshot: queries whose eligible keyframes number
    /// `vpr.approximate_from` or more take their candidates from it
    /// instead of scanning every one. Costs a fraction of a millisecond
    /// of one core per insert and a few hundred bytes a keyframe.
    pub neighbour_graph: bool,
    /// Length the neighbour graph shortens longer descriptors to, by a
    /// fixed random rotation, before it stores them (0: their own
    /// length). Its candidates are scored with the whole descriptor, so
    /// this only trades the graph's insert cost and memory against how
    /// often it proposes the exact answer. A saved graph of another
    /// length is rebuilt at start.
    pub neighbour_graph_length: usize,
    /// With `neighbour_graph`, give every map of `vpr.approximate_from`
    /// keyframes or more a graph of its own as well, which a loop query
    /// over that one map walks instead of an exact pass over it (a few
    /// hundred more bytes a keyframe of such maps, and a second insert).
    /// Not saved: rebuilt in the background at start, loop queries taking
    /// the exact pass meanwhile.
    pub map_graphs: bool,
}

/// Where the index keeps its f32 descriptors (`store.descriptors`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DescriptorStorage {
    /// In unnamed files in `store.data_dir` once the scan reads the codes
    /// first (`vpr.scan`: from 32 768 keyframes on CPUs with a fast code
    /// kernel) and they take [`AUTO_FILE_MIN_BYTES`] or more, in memory
    /// before.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always in the file (an f32 scan then reads the file).
    File,
}

/// Bytes of f32 descriptors from which `store.descriptors = "auto"` moves
/// them out of memory. Below, they cost little memory, and the rows a query
/// scores exactly (a few thousand, whatever the store's size) are a larger
/// share of a short scan: in a 105k × 1280-d fleet run, reading them from
/// the file made each scan about 20 % slower; at 1M × 512 it costs nothing
/// measurable.
pub const AUTO_FILE_MIN_BYTES: u64 = 1 << 30;

impl StoreConfig {
    /// When the descriptors leave memory under `scan` (None: never), for
    /// [`humem_store::StoreOptions`].
    pub fn descriptors_to_file(&self, scan: humem_core::vpr::params::ScanMode) -> Option<FileRule> {
        match self.descriptors {
            DescriptorStorage::Auto => {
                humem_core::vpr::scan::codes_first_from(scan).map(|min_keyframes| FileRule {
                    min_keyframes,
                    min_bytes: AUTO_FILE_MIN_BYTES,
                })
            }
            DescriptorStorage::Memory => None,
            DescriptorStorage::File => Some(FileRule::from_keyframes(0)),
        }
    }
}

impl Default for StoreConfig {
    fn default() -> Self {
        StoreConfig {
            data_dir: PathBuf::from("./data"),
            descriptor_dim: 0,
            write_queue: 1024,
            scene_top_k: 16,
            snapshot_every: humem_store::DEFAULT_SNAPSHOT_EVERY,
            min_free_bytes: humem_store::disk::DEFAULT_MIN_FREE_BYTES,
            descriptors: DescriptorStorage::Auto,
            cache_bytes: humem_store::DEFAULT_CACHE_BYTES,
            neighbour_graph: true,
            neighbour_graph_length: humem_core::engine::graph::SHORT_LENGTH,
            map_graphs: true,
        }
    }
}

/// Defaults of query fields a client leaves unset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QueryDefaults {
    /// Minimum source-frame gap to keyframes of the querying session.
    pub min_frame_gap: u64,
    /// Queries of one robot, session and kind waiting behind the running
    /// one; a newer query supersedes the oldest waiting (latest wins).
    pub pending_per_client: usize,
    /// Threads one query's scan is split across, shared by all queries
    /// (0: every core). Fewer leaves cores to the store writer and the
    /// perception models under full query load.
    pub scan_threads: usize,
    /// Scans that run at once, across all robots; the rest wait their
    /// turn in arrival order. 0: one more than the scan threads. An exact
    /// pass spreads over every scan thread, but a walk of a neighbour
    /// graph runs on one, so on a large store most scans use one core
    /// each, and one more keeps the cores busy while a scan waits (for
    /// the index's lock, or for a core the store writer holds).
    pub concurrent_scans: usize,
    /// Longest a query may take from its arrival to its answer, in
    /// milliseconds; a query expected to take longer (or longer than its
    /// gRPC deadline) is refused at once with RESOURCE_EXHAUSTED and a
    /// `retry-after-ms` hint.
    pub max_wait_ms: u64,
}

impl Default for QueryDefaults {
    fn default() -> Self {
        QueryDefaults {
            min_frame_gap: 100,
            pending_per_client: 1,
            scan_threads: 0,
            concurrent_scans: 0,
            max_wait_ms: 250,
        }
    }
}

/// Log output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogConfig {
    /// `plain` or `json`.
    pub format: LogFormat,
    /// A `tracing` filter, e.g. `info` or `humem=debug,info`.
    pub filter: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            format: LogFormat::Plain,
            // ONNX Runtime warns, harmlessly, about the stripped output shapes
            // of the PP-OCR models each time they load.
            filter: "info,ort::logging=error".into(),
        }
    }
}

/// How log lines are written (`plain` or `json` in TOML and on the
/// command line).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable text, one event a line.
    Plain,
    /// One JSON object a line, for log collectors.
    Json,
}

/// Errors of loading the configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The configuration file named does not exist.
    #[error("configuration file {0} does not exist")]
    MissingFile(PathBuf),
    /// A layer could not be read or merged (unknown key, wrong type, bad
    /// TOML), or a setting is out of range; the message names the setting.
    #[error("configuration: {0}")]
    Invalid(String),
}

/// `HUMEM_*` variables that are not settings: HUMEM_CONFIG names the
/// file, HUMEM_SERVER_URL, HUMEM_TOKEN and HUMEM_TLS_* are for the clients,
/// HUMEM_BIN names the binary for test scripts, HUMEM_ORT_PACKAGE is read by
/// scripts/setup-models.sh, and HUMEM_CODE_KERNEL picks a slower scan
/// kernel for benchmarks (humem_core::engine::kernels).
const NOT_SETTINGS: [&str; 10] = [
    "config",
    "server_url",
    "token",
    "tls_ca",
    "tls_cert",
    "tls_key",
    "tls_server_name",
    "bin",
    "ort_package",
    "code_kernel",
];

/// Whether `HUMEM_<name>` is a setting (`name` without the prefix, any
/// case): every such variable is, except the few [`NOT_SETTINGS`].
pub fn is_setting(name: &str) -> bool {
    !NOT_SETTINGS
        .iter()
        .any(|not| name.eq_ignore_ascii_case(not))
}

impl Config {
    /// Loads defaults < `file` (if given) < `HUMEM_*` environment, then
    /// applies `overrides` (from flags) on top.
    pub fn load(file: Option<&Path>, overrides: Figment) -> Result<Config, ConfigError> {
        let mut figment = Figment::from(Serialized::defaults(Config::default()));
        if let Some(file) = file {
            if !file.exists() {
                return Err(ConfigError::MissingFile(file.to_path_buf()));
            }
            figment = figment.merge(Toml::file(file));
        }
        let env = Env::prefixed("HUMEM_")
            .filter(|key| is_setting(key.as_str()))
            .split("__");
        let config: Config = figment
            .merge(env)
            .merge(overrides)
            .extract()
            .map_err(|e| ConfigError::Invalid(e.to_string()))?;
        config.validate()?;
        Ok(config)
    }

    fn validate(&self) -> Result<(), ConfigError> {
        self.vpr
            .validate()
            .map_err(|e| ConfigError::Invalid(format!("vpr.{e}")))?;
        self.perception.validate().map_err(ConfigError::Invalid)?;
        if self.store.scene_top_k == 0 {
            return Err(ConfigError::Invalid(
                "store.scene_top_k must be at least 1".into(),
            ));
        }
        if self.store.write_queue == 0 {
            return Err(ConfigError::Invalid(
                "store.write_queue must be at least 1".into(),
            ));
        }
        self.server.tls.validate().map_err(ConfigError::Invalid)?;
        for (group, robots) in &self.auth.groups {
            if robots.iter().any(String::is_empty) {
                return Err(ConfigError::Invalid(format!(
                    "auth.groups.{group}: robot ids must not be empty"
                )));
            }
        }
        self.cluster.validate().map_err(ConfigError::Invalid)?;
        if self.server.max_message_bytes < 1024 {
            return Err(ConfigError::Invalid(
                "server.max_message_bytes must be at least 1024".into(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_run_out_of_the_box() {
        let config = Config::load(None, Figment::new()).unwrap();
        assert_eq!(config.server.listen.to_string(), "127.0.0.1:50051");
        assert_eq!(config.store.data_dir, PathBuf::from("./data"));
        assert_eq!(config.query.min_frame_gap, 100);
        assert_eq!(config.vpr, VprParams::default());
        assert_eq!(config.store.cache_bytes, humem_store::DEFAULT_CACHE_BYTES);
    }

    #[test]
    fn file_then_flags_override_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        std::fs::write(
            &file,
            "[store]\ndata_dir = \"/var/lib/humem\"\n[vpr]\ntau_s = 0.5\n[log]\nformat = \"json\"\n",
        )
        .unwrap();
        let flags = Figment::new().merge(Serialized::default("server.listen", "0.0.0.0:1"));
        let config = Config::load(Some(&file), flags).unwrap();
        assert_eq!(config.store.data_dir, PathBuf::from("/var/lib/humem"));
        assert_eq!(config.vpr.tau_s, 0.5);
        assert_eq!(config.log.format, LogFormat::Json);
        assert_eq!(config.server.listen.to_string(), "0.0.0.0:1");
    }

    #[test]
    fn where_the_descriptors_live_follows_the_scan() {
        use humem_core::vpr::params::ScanMode;
        use humem_core::vpr::scan::{codes_first_from, COMPRESSED_MIN_ROWS};
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        let load = |text: &str| {
            std::fs::write(&file, text).unwrap();
            Config::load(Some(&file), Figment::new())
        };
        let defaults = Config::load(None, Figment::new()).unwrap();
        assert_eq!(defaults.store.descriptors, DescriptorStorage::Auto);
        let auto = defaults.store.descriptors_to_file(ScanMode::Auto);
        assert_eq!(
            auto.map(|rule| rule.min_keyframes),
            codes_first_from(ScanMode::Auto)
        );
        if let Some(rule) = auto {
            assert_eq!(rule.min_keyframes, COMPRESSED_MIN_ROWS);
            assert!(
                !rule.applies(105_632, 1280),
                "a 0.5 GB store stays in memory"
            );
            assert!(rule.applies(1_000_000, 512), "a 2 GB store does not");
        }
        let exact = load("[vpr]\nscan = \"exact\"\n").unwrap();
        assert_eq!(exact.store.descriptors_to_file(exact.vpr.scan), None);
        let forced = load("[store]\ndescriptors = \"file\"\n[vpr]\nscan = \"exact\"\n").unwrap();
        assert_eq!(
            forced.store.descriptors_to_file(forced.vpr.scan),
            Some(FileRule::from_keyframes(0))
        );
        let memory = load("[store]\ndescriptors = \"memory\"\n").unwrap();
        assert_eq!(memory.store.descriptors_to_file(ScanMode::Compressed), None);
        let err = load("[store]\ndescriptors = \"disk\"\n").unwrap_err();
        assert!(err.to_string().contains("disk"), "{err}");
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        std::fs::write(&file, "[store]\ndata_dri = \"x\"\n").unwrap();
        let err = Config::load(Some(&file), Figment::new()).unwrap_err();
        assert!(err.to_string().contains("data_dri"), "{err}");
        std::fs::write(&file, "[vpr]\nsigma_m = -1.0\n").unwrap();
        let err = Config::load(Some(&file), Figment::new()).unwrap_err();
        assert!(err.to_string().contains("sigma_m"), "{err}");
        assert!(matches!(
            Config::load(Some(&dir.path().join("nope.toml")), Figment::new()),
            Err(ConfigError::MissingFile(_))
        ));
    }

    #[test]
    fn a_users_model_runs_in_fp32_unless_it_says_int8() {
        use humem_perception::config::Precision;
        let defaults = Config::load(None, Figment::new()).unwrap();
        assert_eq!(defaults.perception.descriptor.precision(), Precision::Int8);
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        let section =
            "[perception.descriptor]\nmodel = \"/opt/eigenplaces.onnx\"\noutput = \"descriptor\"\n";
        std::fs::write(&file, section).unwrap();
        let config = Config::load(Some(&file), Figment::new()).unwrap();
        assert_eq!(config.perception.descriptor.precision(), Precision::Fp32);
        std::fs::write(&file, format!("{section}precision = \"int8\"\n")).unwrap();
        let config = Config::load(Some(&file), Figment::new()).unwrap();
        assert_eq!(config.perception.descriptor.precision(), Precision::Int8);
        // The shipped model named again keeps its default.
        std::fs::write(
            &file,
            "[perception.descriptor]\nmodel = \"efficientnet-lite0/efficientnet_lite0.onnx\"\n",
        )
        .unwrap();
        let config = Config::load(Some(&file), Figment::new()).unwrap();
        assert_eq!(config.perception.descriptor.precision(), Precision::Int8);
    }

    #[test]
    fn cluster_settings_are_checked_at_load() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        std::fs::write(
            &file,
            "[cluster]\nenabled = true\nnats_urls = [\"nats://n1:4222\"]\n[cluster.tls]\nca = \"ca.crt\"\n",
        )
        .unwrap();
        let config = Config::load(Some(&file), Figment::new()).unwrap();
        assert!(config.cluster.enabled);
        assert_eq!(config.cluster.stream_replicas, 3);
        for (text, field) in [
            ("stream_replicas = 0", "stream_replicas"),
            ("nats_urls = []", "nats_urls"),
            ("subject = \"humem.>\"", "subject"),
            ("publish_timout_ms = 5", "publish_timout_ms"),
        ] {
            std::fs::write(&file, format!("[cluster]\nenabled = true\n{text}\n")).unwrap();
            let err = Config::load(Some(&file), Figment::new()).unwrap_err();
            assert!(err.to_string().contains(field), "{text}: {err}");
        }
    }

    #[test]
    fn calibration_and_contradiction_settings_are_checked_at_load() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("humem.toml");
        std::fs::write(
            &file,
            "[vpr]
calibration = \"raw\"\ng_xt = 0.5\n",
        )
        .unwrap();
        let config = Config::load(Some(&file), Figment::new()).unwrap();
        assert_eq!(
            config.vpr.calibration,
            humem_core::vpr::params::Calibration::Raw
        );
        assert_eq!(config.vpr.threshold(), 0.70);
        assert_eq!(config.vpr.g_xt, 0.5);
        for (text, field) in [
            ("calibration = \"zscore\"", "calibration"),
            ("tau_c = 1.2", "tau_c"),
            ("null_min_samples = 0", "null_min_samples"),
            ("contradiction_agreement = -0.1", "contradiction_agreement"),
            ("g_xo = -1.0", "g_xo"),
        ] {
            std::fs::write(&file, format!("[vpr]\n{text}\n")).unwrap();
            let err = Config::load(Some(&file), Figment::new()).unwrap_err();
            assert!(err.to_string().contains(field), "{text}: {err}");
        }
    }
}
