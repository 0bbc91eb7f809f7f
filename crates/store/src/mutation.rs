//! The changes the store applies ([`Mutation`], [`PoseUpdate`]), what
//! each did ([`MutationOutcome`]), and the same for entries of a
//! replicated log ([`LogEntry`], [`LogApplied`]).
//!
//! These are the writer's input and output and the cluster's log format
//! (`humem-cluster` carries a [`Mutation`] in each entry), so they live in
//! a leaf module that the writer and the crate root both use.

use humem_core::index::MapKey;
use humem_core::keyframe::{Pose, SemanticKeyframe, SessionKey};
use humem_core::verdict::Verdict;

use crate::error::StoreError;

/// One change to the store, as the writer applies it. Serializable, so that
/// a replicated log can carry it (`humem-cluster`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Mutation {
    /// Store keyframes (replacing same keys), atomically.
    Insert(Vec<SemanticKeyframe>),
    /// Remove keyframes of one session.
    Erase {
        /// The session the keyframes belong to.
        session: SessionKey,
        /// Keyframe ids within the session; ids not stored are skipped.
        keyframe_ids: Vec<u64>,
    },
    /// Remove every keyframe of one map.
    ResetMap(MapKey),
    /// Remove every keyframe of one session.
    ResetSession(SessionKey),
    /// Move keyframes of one session to new poses (and maybe maps).
    UpdatePoses {
        /// The session the keyframes belong to.
        session: SessionKey,
        /// One corrected pose per keyframe.
        updates: Vec<PoseUpdate>,
    },
    /// Record SLAM's verdict on a proposed candidate (both keyframes must
    /// be stored; the newest verdict on a pair and kind replaces older).
    /// Last but one, so that log entries of the other kinds keep their
    /// encoding.
    ReportVerdict(Verdict),
    /// Store keyframes as [`Mutation::Insert`] does, unless a robot would
    /// then hold more than `max_per_robot` keyframes (a replaced keyframe
    /// adds nothing): then the whole change is refused with
    /// [`StoreError::QuotaExceeded`]. The writer checks it against sled as
    /// it applies changes one by one, so concurrent inserts (and, in
    /// cluster mode, inserts through different replicas, applied in the
    /// log's order everywhere) can never pass the quota together. Last, so
    /// that log entries of the other kinds keep their encoding.
    InsertWithin {
        /// The keyframes, stored atomically.
        keyframes: Vec<SemanticKeyframe>,
        /// Keyframes a robot may hold.
        max_per_robot: u64,
    },
}

/// A corrected pose for one keyframe of a session.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseUpdate {
    /// Keyframe id, unique within the session.
    pub keyframe_id: u64,
    /// The corrected camera pose in its map.
    pub pose: Pose,
    /// The map the keyframe now belongs to, if a merge moved it.
    pub map_id: Option<u64>,
}

/// What a mutation did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MutationOutcome {
    /// Keyframes inserted that replaced stored ones.
    pub replaced: u64,
    /// Keyframes removed, or updated for pose updates.
    pub affected: u64,
    /// Keyframe ids of a pose update that are not stored.
    pub missing: Vec<u64>,
    /// Keyframes in the store afterwards.
    pub store_keyframes: u64,
    /// Verdicts in the store afterwards.
    pub store_verdicts: u64,
}

/// A change taken from a replicated log, at its position there (1, 2, …).
#[derive(Debug, Clone)]
pub struct LogEntry {
    /// The entry's position in the log; recorded with the change.
    pub position: u64,
    /// The change.
    pub mutation: Mutation,
}

/// What became of a batch of [`LogEntry`]s ([`crate::Store::apply_log`]).
#[derive(Debug, Default)]
pub struct LogApplied {
    /// One result per entry applied, in order. An entry refused for what it
    /// is ([`StoreError::is_refusal`]) is refused alike on every replica:
    /// it counts as applied, with its error.
    pub results: Vec<Result<MutationOutcome, StoreError>>,
    /// Why the entries after `results` were not applied (a full disk, a
    /// failed write): they must be given again, in order.
    pub stopped: Option<StoreError>,
}
