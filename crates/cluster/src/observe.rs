//! What the cluster reports, for metrics: a trait the server implements
//! with Prometheus, so this crate stays free of any metrics library (as
//! `humem_core::observe` does for the queues).

use std::time::Duration;

/// Receives the replica's progress. Called on the applier's path: cheap,
/// never blocking.
pub trait ClusterObserver: Send + Sync {
    /// Entries were applied; `delay` is, for the newest of them, the time
    /// from its storing in the stream to its apply here.
    fn applied(&self, entries: usize, position: u64, delay: Duration);
    /// Entries in the stream after this replica's position.
    fn lag(&self, entries: u64);
    /// The stream, as its leader reports it: its last sequence, and how
    /// many of its copies are current (the leader's included) out of
    /// `replicas`.
    fn stream(&self, last_sequence: u64, current: usize, replicas: usize);
    /// A publish ended after `elapsed`: `ok`, `duplicate` or `failed`.
    fn published(&self, outcome: &'static str, elapsed: Duration);
    /// Connected to NATS, or not.
    fn connected(&self, up: bool);
    /// The applier stopped (`true`) and waits for an operator, or goes on.
    fn halted(&self, halted: bool);
    /// An entry that is not a HuMem entry was skipped.
    fn skipped(&self);
}

/// An observer that records nothing, for tests and tools.
#[derive(Debug, Default, Clone, Copy)]
pub struct Unobserved;

impl ClusterObserver for Unobserved {
    fn applied(&self, _: usize, _: u64, _: Duration) {}
    fn lag(&self, _: u64) {}
    fn stream(&self, _: u64, _: usize, _: usize) {}
    fn published(&self, _: &'static str, _: Duration) {}
    fn connected(&self, _: bool) {}
    fn halted(&self, _: bool) {}
    fn skipped(&self) {}
}
