//! Cluster-mode metrics: how far this replica is behind the write log, how
//! fast it applies, the stream's health, and the cost of a write's trip
//! through JetStream. Fed by [`humem_cluster::ClusterObserver`]; every
//! series exists from the start, at 0, on every server (a dashboard of a
//! server not in cluster mode shows zeros, not gaps).

use std::sync::LazyLock;
use std::time::Duration;

use prometheus::{Histogram, HistogramOpts, HistogramVec, IntCounter, IntGauge, Opts};

use super::registry::{latency_buckets, register};

/// Entries in the stream after this replica's position.
pub static LAG: LazyLock<IntGauge> = LazyLock::new(|| {
    register(
        IntGauge::new(
            "humem_cluster_lag_entries",
            "write-log entries this replica has not applied yet",
        )
        .unwrap(),
    )
});

/// The write-log position this replica has applied.
pub static POSITION: LazyLock<IntGauge> = LazyLock::new(|| {
    register(
        IntGauge::new(
            "humem_cluster_applied_position",
            "write-log sequence this replica has applied up to",
        )
        .unwrap(),
    )
});

/// Entries applied (rate: the apply rate).
pub static APPLIED: LazyLock<IntCounter> = LazyLock::new(|| {
    register(
        IntCounter::new(
            "humem_cluster_applied_total",
            "write-log entries this replica has applied",
        )
        .unwrap(),
    )
});

/// From an entry's storing in the stream to its apply here.
pub static APPLY_DELAY: LazyLock<Histogram> = LazyLock::new(|| {
    register(
        Histogram::with_opts(
            HistogramOpts::new(
                "humem_cluster_apply_delay_seconds",
                "time from a write-log entry's storing in JetStream to its apply on this replica (newest entry of each batch)",
            )
            .buckets(latency_buckets()),
        )
        .unwrap(),
    )
});

/// A write's publish to JetStream, by outcome.
pub static PUBLISH: LazyLock<HistogramVec> = LazyLock::new(|| {
    register(
        HistogramVec::new(
            HistogramOpts::new(
                "humem_cluster_publish_seconds",
                "time to have a write stored by JetStream, retries included, by outcome (ok, duplicate, failed)",
            )
            .buckets(latency_buckets()),
            &["outcome"],
        )
        .unwrap(),
    )
});

/// The stream's last sequence, as its leader reports it.
pub static STREAM_LAST: LazyLock<IntGauge> = LazyLock::new(|| {
    register(
        IntGauge::new(
            "humem_cluster_stream_last_sequence",
            "last sequence of the write-log stream (0: its state is unknown)",
        )
        .unwrap(),
    )
});

/// Copies of the stream that are current, and configured.
pub static STREAM_REPLICAS: LazyLock<prometheus::IntGaugeVec> = LazyLock::new(|| {
    register(
        prometheus::IntGaugeVec::new(
            Opts::new(
                "humem_cluster_stream_replicas",
                "copies of the write-log stream: state=current (leader included) or configured",
            ),
            &["state"],
        )
        .unwrap(),
    )
});

/// 1 while connected to NATS.
pub static CONNECTED: LazyLock<IntGauge> = LazyLock::new(|| {
    register(IntGauge::new("humem_cluster_connected", "1 while connected to NATS").unwrap())
});

/// 1 once the applier has stopped for good.
pub static HALTED: LazyLock<IntGauge> = LazyLock::new(|| {
    register(
        IntGauge::new(
            "humem_cluster_halted",
            "1 when this replica stopped applying the write log and needs an operator",
        )
        .unwrap(),
    )
});

/// Entries skipped as not HuMem's.
pub static SKIPPED: LazyLock<IntCounter> = LazyLock::new(|| {
    register(
        IntCounter::new(
            "humem_cluster_skipped_entries_total",
            "write-log entries skipped because they are not HuMem entries",
        )
        .unwrap(),
    )
});

/// Creates every series, at 0.
pub(super) fn init() {
    for outcome in ["ok", "duplicate", "failed"] {
        PUBLISH.with_label_values(&[outcome]);
    }
    for state in ["current", "configured"] {
        STREAM_REPLICAS.with_label_values(&[state]);
    }
    LazyLock::force(&LAG);
    LazyLock::force(&POSITION);
    LazyLock::force(&APPLIED);
    LazyLock::force(&APPLY_DELAY);
    LazyLock::force(&STREAM_LAST);
    LazyLock::force(&CONNECTED);
    LazyLock::force(&HALTED);
    LazyLock::force(&SKIPPED);
}

/// The observer the server hands to its replica.
#[derive(Debug, Clone, Copy)]
pub struct PrometheusCluster;

impl humem_cluster::ClusterObserver for PrometheusCluster {
    fn applied(&self, entries: usize, position: u64, delay: Duration) {
        APPLIED.inc_by(entries as u64);
        POSITION.set(i64::try_from(position).unwrap_or(i64::MAX));
        APPLY_DELAY.observe(delay.as_secs_f64());
    }

    fn lag(&self, entries: u64) {
        LAG.set(i64::try_from(entries).unwrap_or(i64::MAX));
    }

    fn stream(&self, last_sequence: u64, current: usize, replicas: usize) {
        STREAM_LAST.set(i64::try_from(last_sequence).unwrap_or(i64::MAX));
        STREAM_REPLICAS
            .with_label_values(&["current"])
            .set(current as i64);
        STREAM_REPLICAS
            .with_label_values(&["configured"])
            .set(replicas as i64);
    }

    fn published(&self, outcome: &'static str, elapsed: Duration) {
        PUBLISH
            .with_label_values(&[outcome])
            .observe(elapsed.as_secs_f64());
    }

    fn connected(&self, up: bool) {
        CONNECTED.set(i64::from(up));
    }

    fn halted(&self, halted: bool) {
        HALTED.set(i64::from(halted));
    }

    fn skipped(&self) {
        SKIPPED.inc();
    }
}
