//! Queue observation: how the store's writer and the model batchers report
//! their queue depth and batch sizes without knowing who listens.
//!
//! The server hands in an observer that feeds Prometheus; tools and tests
//! hand in [`Unobserved`]. A trait rather than metric handles keeps the store
//! and perception crates free of any metrics library, and one observer
//! serves every queue, named by its label.

use std::sync::Arc;

/// Receives the changes of named queues. Called on hot paths: implementations
/// must be cheap and must not block.
pub trait QueueObserver: Send + Sync {
    /// `queue` gained (positive) or lost (negative) `delta` waiting jobs.
    fn depth_changed(&self, queue: &'static str, delta: i64);
    /// `queue` ran one batch of `size` jobs together.
    fn batch_ran(&self, queue: &'static str, size: usize);
}

/// An observer that records nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Unobserved;

impl QueueObserver for Unobserved {
    fn depth_changed(&self, _queue: &'static str, _delta: i64) {}
    fn batch_ran(&self, _queue: &'static str, _size: usize) {}
}

/// A shared observer, as the store and the batchers hold it.
pub type SharedObserver = Arc<dyn QueueObserver>;

/// The observer that records nothing, shared.
pub fn unobserved() -> SharedObserver {
    Arc::new(Unobserved)
}
