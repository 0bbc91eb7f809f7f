//! The one Prometheus registry every HuMem metric is in, the registration
//! helper, and the latency buckets the duration histograms share.
//!
//! A leaf of [`super`]: the service's metrics (the parent module) and the
//! cluster-mode metrics ([`super::cluster`]) both register through it
//! without one using the other.

use std::sync::LazyLock;

use prometheus::Registry;

/// The registry every HuMem metric is in.
pub static REGISTRY: LazyLock<Registry> = LazyLock::new(Registry::new);

/// Registers `collector` in [`REGISTRY`] and gives it back.
pub(super) fn register<C: prometheus::core::Collector + Clone + 'static>(collector: C) -> C {
    REGISTRY
        .register(Box::new(collector.clone()))
        .expect("metric names are unique");
    collector
}

/// Latency buckets from 250 µs to 10 s, with edges at the budgets a SLAM
/// operator sets (e.g. 100 ms per frame, 250 ms per query) so quantiles near
/// them are not smeared over a wide bucket.
pub(super) fn latency_buckets() -> Vec<f64> {
    vec![
        0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5,
        5.0, 10.0,
    ]
}
