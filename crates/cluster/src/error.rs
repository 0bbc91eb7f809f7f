//! [`ClusterError`], the one error type of cluster mode, in a leaf module
//! of its own so that every other module (NATS, the replica, the
//! snapshots) can return it without importing the crate root.

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
