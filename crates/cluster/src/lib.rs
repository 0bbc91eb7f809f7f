//! Cluster mode: several HuMem servers share one store through a replicated
//! write log on NATS JetStream.
//!
//! Every write (insert, erase, resets, pose updates) is published to one
//! stream with JetStream's replicas and de-duplication by message id; the
//! client is answered only after JetStream has stored it and this replica
//! has applied it. Every replica reads the stream in order into its own
//! sled store and index, recording the last applied position with each
//! change, so replicas converge to the same state and answer queries
//! locally. We write no replication or consensus of our own: ordering,
//! copies and fail-over are JetStream's.
//!
//! Layering: this crate sits on `humem-store` (which applies a log entry
//! and records its position atomically) and knows nothing of gRPC; the
//! server routes its writes here when `[cluster] enabled = true`.
//!
//! - [`config`]: the `[cluster]` settings;
//! - `error`: [`ClusterError`], the errors of cluster mode;
//! - [`entry`]: the log entry format, versioned in a header;
//! - `nats`: connecting (credentials, TLS) and the stream's shape;
//! - `applier`: the in-order reader that applies the log to the store;
//! - `replica`: [`Replica`], writing through the log, waiting for a
//!   position;
//! - [`snapshots`]: store snapshots in a JetStream object store, so the
//!   log can be bounded and a new replica can start from one;
//! - [`observe`]: what the cluster reports, for metrics.
//!
//! Shared types live in leaf modules ([`ClusterError`] in `error`), which
//! the crate root only re-exports: no module imports the root.

mod applier;
pub mod config;
pub mod entry;
mod error;
mod nats;
pub mod observe;
mod replica;
pub mod snapshots;

pub use config::ClusterConfig;
pub use error::ClusterError;
pub use observe::{ClusterObserver, Unobserved};
pub use replica::{Replica, Written};
