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
//! - [`entry`]: the log entry format, versioned in a header;
//! - `nats`: connecting (credentials, TLS) and the stream's shape;
//! - `applier`: the in-order reader that applies the log to the store;
//! - [`Replica`]: writing through the log, waiting for a position;
//! - [`observe`]: what the cluster reports, for metrics.

mod applier;
pub mod config;
pub mod entry;
mod nats;
pub mod observe;
mod replica;
pub mod snapshots;

pub use config::ClusterConfig;
pub use observe::{ClusterObserver, Unobserved};
pub use replica::{Replica, Written};

use humem_store::StoreError;

/// Errors of cluster mode.
#[derive(Debug, thiserror::Error)]
pub enum ClusterError {
    /// A setting or a file it names is wrong.
    #[error("cluster configuration: {0}")]
    Config(String),
    /// NATS or JetStream is unreachable or refused (the message says which).
    #[error("NATS: {0}")]
    Nats(String),
    /// The change is larger than NATS takes in one message.
    #[error("the change is too large for the write log ({0}); send smaller batches or raise max_payload on the NATS servers")]
    TooLarge(String),
    /// The store refused or failed the change.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The change is in the log but this replica has not applied it in time.
    #[error("the change is in the write log (entry {sequence}) but this replica has not applied it: {why}; it will, and another replica may have")]
    NotApplied {
        /// The entry's sequence.
        sequence: u64,
        /// Why not yet.
        why: String,
    },
    /// A read asked for a position this replica has not reached in time.
    #[error("this replica has applied the write log up to entry {applied}, not yet {wanted}; retry, or ask another replica")]
    Behind {
        /// Where this replica is.
        applied: u64,
        /// The position asked for.
        wanted: u64,
    },
    /// This store and the stream disagree: the replica must not start.
    #[error("{0}")]
    Diverged(String),
    /// The applier stopped for good; the replica needs an operator.
    #[error("this replica stopped applying the write log: {0}")]
    Halted(String),
}
