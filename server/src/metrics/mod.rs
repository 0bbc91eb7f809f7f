//! Prometheus metrics: what the service exposes for Grafana and alerting.
//!
//! The metrics are process-wide statics in one registry, so that any layer
//! (the batcher, the query scheduler, the handlers) records where the event
//! happens without threading a handle through every call. Names follow
//! Prometheus conventions: `humem_` prefix, base units, `_total` counters,
//! `_seconds` durations. Gauges that describe the store (keyframes per map,
//! bytes on disk) are computed when scraped. The exposition is the
//! `prometheus` crate's text encoder, served over HTTP by axum. The
//! cluster-mode metrics, fed by the replica's observer, are in [`cluster`].
//! The registry itself and the helpers both use are in [`registry`], a
//! leaf, so that [`cluster`] does not reach up into this module.

pub mod cluster;
pub mod registry;

use std::net::SocketAddr;
use std::sync::LazyLock;

use prometheus::{
    Encoder, Gauge, GaugeVec, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge,
    IntGaugeVec, Opts, TextEncoder,
};

use humem_core::observe::{QueueObserver, SharedObserver};
use humem_store::{IndexSource, Store};

pub use registry::REGISTRY;
use registry::{latency_buckets, register};

/// The API's methods, as the `rpc` label of every per-RPC metric.
pub const RPCS: [&str; 9] = [
    "Insert",
    "InsertBatch",
    "Query",
    "Erase",
    "ResetMap",
    "ResetSession",
    "UpdatePoses",
    "Stats",
    "ReportVerification",
];

/// Always 1, labelled with the server's version, to tell a fleet's
/// sidecars apart.
pub static BUILD_INFO: LazyLock<IntGaugeVec> = LazyLock::new(|| {
    register(
        IntGaugeVec::new(
            Opts::new("humem_build_info", "HuMem server version (always 1)"),
            &["version"],
        )
        .unwrap(),
    )
});

/// Requests per RPC and gRPC status code.
pub static RPC_REQUESTS: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_rpc_requests_total",
                "gRPC requests by RPC and status code",
            ),
            &["rpc", "code"],
        )
        .unwrap(),
    )
});

/// Latency per RPC.
pub static RPC_DURATION: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new("humem_rpc_duration_seconds", "gRPC request latency by RPC")
                .buckets(latency_buckets()),
            &["rpc"],
        )
        .unwrap(),
    )
});

/// Time per pipeline stage (decode, each model, each VPR layer).
pub static STAGE_DURATION: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new(
                "humem_stage_duration_seconds",
                "time per request in each stage: decode, descriptor, scene, detector, ocr_det, ocr_rec, scal, osrl, ogtl, fusion, rules",
            )
            .buckets(latency_buckets()),
            &["stage"],
        )
        .unwrap(),
    )
});

/// Inputs per model inference.
pub static BATCH_SIZE: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new("humem_batch_size", "inputs per model inference")
                .buckets(vec![1.0, 2.0, 4.0, 8.0, 16.0, 32.0]),
            &["model"],
        )
        .unwrap(),
    )
});

/// Jobs waiting per queue (model queues, the store writer, query slots).
pub static QUEUE_DEPTH: LazyLock<IntGaugeVec> = LazyLock::new(|| {
    register(
        IntGaugeVec::new(
            Opts::new("humem_queue_depth", "jobs waiting, by queue"),
            &["queue"],
        )
        .unwrap(),
    )
});

/// Queries answered as superseded (latest wins), by query kind.
pub static QUERIES_SUPERSEDED: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_queries_superseded_total",
                "queries displaced by a newer query of the same client",
            ),
            &["kind"],
        )
        .unwrap(),
    )
});

/// Queries refused because the scans ahead would outlast their wait, by
/// query kind.
pub static QUERIES_REFUSED: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_queries_refused_total",
                "queries refused with RESOURCE_EXHAUSTED: the expected wait for a scan exceeded what the query could wait",
            ),
            &["kind"],
        )
        .unwrap(),
    )
});

/// Images whose objects were carried over (`perception.reuse`).
pub static OBJECTS_CARRIED: LazyLock<IntCounter> = LazyLock::new(|| {
    register(
        IntCounter::new(
            "humem_perception_objects_carried_total",
            "images whose objects and text were carried over from the last read of their session \
             instead of detected and read (perception.reuse)",
        )
        .unwrap(),
    )
});

/// Keyframes stored by Insert and InsertBatch.
pub static KEYFRAMES_INSERTED: LazyLock<IntCounter> = LazyLock::new(|| {
    register(IntCounter::new("humem_keyframes_inserted_total", "keyframes stored").unwrap())
});

/// Candidates returned per answered query.
pub static CANDIDATES: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new(
                "humem_query_candidates",
                "candidates returned per answered query",
            )
            .buckets(vec![0.0, 1.0, 2.0, 3.0, 5.0, 10.0, 25.0]),
            &["kind"],
        )
        .unwrap(),
    )
});

/// Fused scores Λ of returned candidates.
pub static CANDIDATE_SCORE: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new(
                "humem_candidate_score",
                "fused score of returned candidates",
            )
            .buckets(prometheus::linear_buckets(0.5, 0.05, 10).expect("valid buckets")),
            &["kind"],
        )
        .unwrap(),
    )
});

/// The store's operating threshold as of the last answered query: the
/// configured one, or the one its verdicts adapted
/// (`vpr.verdicts.adapt_threshold`). A rise says the candidates sent to
/// verification were falling short of the target precision.
pub static OPERATING_THRESHOLD: LazyLock<Gauge> = LazyLock::new(|| {
    register(
        Gauge::new(
            "humem_operating_threshold",
            "the threshold queries naming none were answered at, as of the last answered query (configured, or adapted from verdicts)",
        )
        .unwrap(),
    )
});

/// Keyframes in the store per map (computed when scraped).
pub static KEYFRAMES: LazyLock<IntGaugeVec> = LazyLock::new(|| {
    register(
        IntGaugeVec::new(
            Opts::new(
                "humem_keyframes",
                "keyframes stored, by robot, session and map",
            ),
            &["robot", "session", "map"],
        )
        .unwrap(),
    )
});

/// Store size on disk (computed when scraped).
pub static STORE_BYTES: LazyLock<IntGauge> = LazyLock::new(|| {
    register(IntGauge::new("humem_store_disk_bytes", "size of the sled store on disk").unwrap())
});

/// How the store was opened at start: seconds to a ready index, by where
/// the index came from (`snapshot` or `tree`).
pub static STORE_OPEN: LazyLock<GaugeVec> = LazyLock::new(|| {
    register(
        GaugeVec::new(
            Opts::new(
                "humem_store_open_seconds",
                "time the store took to open at start, by where the index came from (snapshot or tree)",
            ),
            &["source"],
        )
        .unwrap(),
    )
});

/// Keyframe keys replayed from the write journal at open.
pub static STORE_REPLAYED: LazyLock<IntGauge> = LazyLock::new(|| {
    register(
        IntGauge::new(
            "humem_store_open_replayed_keyframes",
            "keyframe keys replayed from the write journal over the index snapshot at start",
        )
        .unwrap(),
    )
});

/// Reloads of the TLS certificate files, by result (`ok`, `error`: the
/// previous certificate stays in use).
pub static TLS_RELOADS: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_tls_reloads_total",
                "reloads of the TLS certificate files after they changed, by result",
            ),
            &["result"],
        )
        .unwrap(),
    )
});

/// TLS handshakes that failed or timed out on the gRPC port.
pub static TLS_HANDSHAKE_FAILURES: LazyLock<IntCounter> = LazyLock::new(|| {
    register(
        IntCounter::new(
            "humem_tls_handshake_failures_total",
            "TLS handshakes on the gRPC port that failed or timed out",
        )
        .unwrap(),
    )
});

/// Requests refused by authentication or access rules, by RPC and reason
/// (`unauthenticated`, `permission_denied`): bounded labels, no robot ids.
pub static AUTH_DENIED: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_auth_denied_total",
                "requests refused for a missing or invalid credential or for acting beyond it, by RPC and reason",
            ),
            &["rpc", "reason"],
        )
        .unwrap(),
    )
});

/// Requests refused for a per-robot quota, by kind (`insert_rate`,
/// `query_rate`, `store_size`); no robot label, so bounded.
pub static QUOTA_REFUSED: LazyLock<IntCounterVec> = LazyLock::new(|| {
    register(
        IntCounterVec::new(
            Opts::new(
                "humem_quota_refused_total",
                "requests refused because a robot was over a quota, by kind",
            ),
            &["kind"],
        )
        .unwrap(),
    )
});

/// Records one finished RPC.
pub fn observe_rpc(rpc: &str, code: tonic::Code, seconds: f64) {
    RPC_REQUESTS
        .with_label_values(&[rpc, code_name(code)])
        .inc();
    RPC_DURATION.with_label_values(&[rpc]).observe(seconds);
}

/// Records the stage timings of one request.
pub fn observe_stages(timings: &[(&'static str, std::time::Duration)]) {
    for (stage, took) in timings {
        STAGE_DURATION
            .with_label_values(&[stage])
            .observe(took.as_secs_f64());
    }
}

/// The gRPC code names of the status codes, as Prometheus label values.
fn code_name(code: tonic::Code) -> &'static str {
    use tonic::Code::*;
    match code {
        Ok => "OK",
        Cancelled => "CANCELLED",
        Unknown => "UNKNOWN",
        InvalidArgument => "INVALID_ARGUMENT",
        DeadlineExceeded => "DEADLINE_EXCEEDED",
        NotFound => "NOT_FOUND",
        AlreadyExists => "ALREADY_EXISTS",
        PermissionDenied => "PERMISSION_DENIED",
        ResourceExhausted => "RESOURCE_EXHAUSTED",
        FailedPrecondition => "FAILED_PRECONDITION",
        Aborted => "ABORTED",
        OutOfRange => "OUT_OF_RANGE",
        Unimplemented => "UNIMPLEMENTED",
        Internal => "INTERNAL",
        Unavailable => "UNAVAILABLE",
        DataLoss => "DATA_LOSS",
        Unauthenticated => "UNAUTHENTICATED",
    }
}

/// Maps that get a `humem_keyframes` series of their own: the largest;
/// the rest are summed into one series labelled `_other`, so a fleet of
/// any size exposes a bounded number of series.
pub const MAX_MAP_SERIES: usize = 200;

/// The text exposition, with the store's gauges brought up to date.
pub async fn render(store: &Store) -> String {
    KEYFRAMES.reset();
    let mut maps = store.index_async().await.map_counts();
    maps.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    let others: usize = maps.iter().skip(MAX_MAP_SERIES).map(|(_, n)| n).sum();
    for (map, count) in maps.iter().take(MAX_MAP_SERIES) {
        KEYFRAMES
            .with_label_values(&[
                map.session.robot_id.as_str(),
                map.session.session_id.as_str(),
                &map.map_id.to_string(),
            ])
            .set(*count as i64);
    }
    if maps.len() > MAX_MAP_SERIES {
        KEYFRAMES
            .with_label_values(&["_other", "_other", "_other"])
            .set(others as i64);
    }
    STORE_BYTES.set(i64::try_from(store.disk_bytes()).unwrap_or(i64::MAX));
    let mut buffer = Vec::new();
    TextEncoder::new()
        .encode(&REGISTRY.gather(), &mut buffer)
        .expect("encoding metrics into memory");
    String::from_utf8(buffer).expect("the text format is UTF-8")
}

/// Touches every static so all metric families exist from the start (a
/// dashboard should see zeros, not missing series).
/// The queues of the store's writer and of the model batchers, reported
/// into [`QUEUE_DEPTH`] and [`BATCH_SIZE`] by queue name.
#[derive(Debug, Clone, Copy)]
struct PrometheusQueues;

impl QueueObserver for PrometheusQueues {
    fn depth_changed(&self, queue: &'static str, delta: i64) {
        QUEUE_DEPTH.with_label_values(&[queue]).add(delta);
    }

    fn batch_ran(&self, queue: &'static str, size: usize) {
        BATCH_SIZE.with_label_values(&[queue]).observe(size as f64);
    }
}

/// The observer the server hands to the store and to perception.
pub fn queue_observer() -> SharedObserver {
    std::sync::Arc::new(PrometheusQueues)
}

/// Registers every metric (so each is exported from the first scrape, at
/// zero) and sets the build info; call once at start.
pub fn init() {
    BUILD_INFO
        .with_label_values(&[env!("CARGO_PKG_VERSION")])
        .set(1);
    // The process's memory, CPU time and open files (process_* metrics).
    #[cfg(target_os = "linux")]
    {
        static PROCESS: std::sync::Once = std::sync::Once::new();
        PROCESS.call_once(|| {
            REGISTRY
                .register(Box::new(
                    prometheus::process_collector::ProcessCollector::for_self(),
                ))
                .expect("registered once");
        });
    }
    for kind in ["loop_closure", "relocalisation"] {
        QUERIES_SUPERSEDED.with_label_values(&[kind]);
        QUERIES_REFUSED.with_label_values(&[kind]);
    }
    for result in ["ok", "error"] {
        TLS_RELOADS.with_label_values(&[result]);
    }
    LazyLock::force(&TLS_HANDSHAKE_FAILURES);
    // Every (rpc, reason) series exists from the start, at 0.
    for rpc in RPCS {
        for reason in ["unauthenticated", "permission_denied"] {
            AUTH_DENIED.with_label_values(&[rpc, reason]);
        }
    }
    for kind in ["insert_rate", "query_rate", "store_size"] {
        QUOTA_REFUSED.with_label_values(&[kind]);
    }
    LazyLock::force(&RPC_REQUESTS);
    LazyLock::force(&RPC_DURATION);
    LazyLock::force(&STAGE_DURATION);
    LazyLock::force(&BATCH_SIZE);
    LazyLock::force(&QUEUE_DEPTH);
    LazyLock::force(&QUERIES_SUPERSEDED);
    LazyLock::force(&QUERIES_REFUSED);
    LazyLock::force(&KEYFRAMES_INSERTED);
    LazyLock::force(&OBJECTS_CARRIED);
    LazyLock::force(&CANDIDATES);
    LazyLock::force(&CANDIDATE_SCORE);
    LazyLock::force(&OPERATING_THRESHOLD);
    LazyLock::force(&KEYFRAMES);
    LazyLock::force(&STORE_BYTES);
    cluster::init();
}

/// Records how the store was opened (it does not change while serving).
pub fn store_opened(store: &Store) {
    let opened = store.opened();
    let (source, replayed) = match opened.source {
        IndexSource::Snapshot { replayed } => ("snapshot", replayed),
        IndexSource::Tree { .. } => ("tree", 0),
    };
    STORE_OPEN
        .with_label_values(&[source])
        .set(opened.elapsed.as_secs_f64());
    STORE_REPLAYED.set(replayed as i64);
}

/// Serves `/metrics` on `listen` until `shutdown` resolves, with plain
/// HTTP probes beside it: `/healthz` (200 while the process answers) and
/// `/readyz` (200 while `serving` is true: the gRPC port is open and no
/// shutdown has begun; else 503). They are for probes that cannot speak
/// TLS to the gRPC port (Kubernetes' gRPC probes cannot), and need no
/// credential, like the gRPC health service.
pub async fn serve(
    listen: SocketAddr,
    store: Store,
    serving: tokio::sync::watch::Receiver<bool>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<SocketAddr> {
    use anyhow::Context;
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .with_context(|| format!("binding the metrics endpoint {listen}"))?;
    let local = listener.local_addr()?;
    let app = axum::Router::new()
        .route(
            "/metrics",
            axum::routing::get(move || {
                let store = store.clone();
                async move {
                    (
                        [(
                            axum::http::header::CONTENT_TYPE,
                            "text/plain; version=0.0.4",
                        )],
                        render(&store).await,
                    )
                }
            }),
        )
        .route("/healthz", axum::routing::get(|| async { "ok\n" }))
        .route(
            "/readyz",
            axum::routing::get(move || {
                let ready = *serving.borrow();
                async move {
                    if ready {
                        (axum::http::StatusCode::OK, "serving\n")
                    } else {
                        (axum::http::StatusCode::SERVICE_UNAVAILABLE, "not serving\n")
                    }
                }
            }),
        );
    tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, app)
            .with_graceful_shutdown(shutdown)
            .await
        {
            tracing::error!(error = %e, "metrics endpoint failed");
        }
    });
    Ok(local)
}
