//! Staging a change: what each kind of
//! [`Mutation`](crate::mutation::Mutation) writes to sled and changes in
//! the index, worked out from sled alone (never the index,
//! which lags the writer by the groups not yet published).
//!
//! A change is gathered into one [`Staged`] (its batches, the keys it
//! touches for the journal and the rollback, its outcome and its index
//! changes) before anything is written, so that a change that fails
//! writes nothing. These are plain functions of the [`Trees`]: the
//! writer ([`super::commit`]) owns the counters, the quota and the
//! transaction that applies a staged change.

use std::collections::HashSet;

use humem_core::index::MapKey;
use humem_core::keyframe::{KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::verdict::Verdict;

use super::trees::Trees;
use crate::codec::{self, decode_record, encode_key, encode_record};
use crate::error::StoreError;
use crate::mutation::{MutationOutcome, PoseUpdate};
use crate::robot_counts::Deltas;

/// One mutation's writes and outcome, gathered before its batch is applied.
#[derive(Default)]
pub(super) struct Staged {
    pub(super) batch: sled::Batch,
    /// The sled keys the batch writes or removes, for the journal.
    pub(super) keys: Vec<Vec<u8>>,
    /// Keyframes the change adds to the store (negative: removes).
    pub(super) added: i64,
    /// The same, per robot.
    pub(super) added_by_robot: Deltas,
    pub(super) outcome: MutationOutcome,
    pub(super) changes: Vec<IndexChange>,
    /// Writes to the verdicts tree, and their count.
    pub(super) verdicts: sled::Batch,
    /// Writes to the by-candidate tree of the verdicts.
    pub(super) verdicts_by_candidate: sled::Batch,
    pub(super) verdict_writes: usize,
    /// The keys the two verdict batches write or remove, for the rollback.
    pub(super) verdict_keys: Vec<Vec<u8>>,
    pub(super) by_candidate_keys: Vec<Vec<u8>>,
    /// Keys of the keyframes the change removes, whose verdicts go too.
    pub(super) removed: Vec<Vec<u8>>,
}

impl Staged {
    /// Stages the removal of a stored keyframe.
    pub(super) fn remove(&mut self, bytes: Vec<u8>, key: KeyframeKey) {
        self.batch.remove(bytes.clone());
        self.removed.push(bytes.clone());
        self.keys.push(bytes);
        self.added -= 1;
        *self.added_by_robot.entry(key.robot_id.clone()).or_default() -= 1;
        self.outcome.affected += 1;
        self.changes.push(IndexChange::Remove(key));
    }

    /// Stages a write to the verdicts tree.
    fn put_verdict(&mut self, key: Vec<u8>, value: Vec<u8>) {
        self.verdicts.insert(key.clone(), value);
        self.verdict_keys.push(key);
    }

    /// Stages a removal from the verdicts tree.
    fn remove_verdict(&mut self, key: Vec<u8>) {
        self.verdicts.remove(key.clone());
        self.verdict_keys.push(key);
    }

    /// Stages a write to the by-candidate tree.
    fn put_by_candidate(&mut self, key: Vec<u8>, value: Vec<u8>) {
        self.verdicts_by_candidate.insert(key.clone(), value);
        self.by_candidate_keys.push(key);
    }

    /// Stages a removal from the by-candidate tree.
    fn remove_by_candidate(&mut self, key: Vec<u8>) {
        self.verdicts_by_candidate.remove(key.clone());
        self.by_candidate_keys.push(key);
    }
}

/// A change to the index, made visible after the flush.
pub(super) enum IndexChange {
    Upsert(SemanticKeyframe),
    Remove(KeyframeKey),
    Move(KeyframeKey, Pose, Option<u64>),
    /// A verdict to record (the removals of verdicts follow the removals of
    /// their keyframes in the index itself).
    Verdict(Verdict),
}

/// Records a verdict, whose two keyframes must be stored.
pub(super) fn verdict(
    trees: &Trees,
    verdict: Verdict,
    staged: &mut Staged,
) -> Result<(), StoreError> {
    for (role, key) in [("query", &verdict.query), ("candidate", &verdict.candidate)] {
        if !trees.keyframes.contains_key(encode_key(key))? {
            return Err(StoreError::UnknownKeyframe {
                role,
                key: key.clone(),
            });
        }
    }
    let key = codec::verdict_key(&verdict);
    if trees.verdicts.contains_key(&key)? {
        staged.outcome.replaced += 1;
    } else {
        staged.outcome.affected += 1;
    }
    staged.put_verdict(key.clone(), codec::encode_verdict(&verdict));
    staged.put_by_candidate(codec::verdict_candidate_key(&verdict), key);
    staged.verdict_writes += 1;
    staged.changes.push(IndexChange::Verdict(verdict));
    Ok(())
}

/// Removes the verdicts naming any keyframe the change removes, as query
/// (a prefix range of the verdicts tree) or as candidate (one of the
/// by-candidate tree).
pub(super) fn verdict_cascade(trees: &Trees, staged: &mut Staged) -> Result<(), StoreError> {
    for removed in std::mem::take(&mut staged.removed) {
        for item in trees.verdicts.scan_prefix(&removed).keys() {
            let key = item?;
            let twin = codec::verdict_twin_key(&key, removed.len());
            staged.remove_verdict(key.to_vec());
            staged.remove_by_candidate(twin);
            staged.verdict_writes += 1;
        }
        for item in trees.verdicts_by_candidate.scan_prefix(&removed) {
            let (key, primary) = item?;
            staged.remove_by_candidate(key.to_vec());
            staged.remove_verdict(primary.to_vec());
            staged.verdict_writes += 1;
        }
    }
    Ok(())
}

/// Stages keyframes to insert or replace, after checking their descriptor
/// length against the store's (`store_dim`; 0: not fixed yet, and the
/// first keyframe sets it). Returns the store's descriptor length with
/// them in; the writer checks the quota and records a new length.
pub(super) fn insert(
    trees: &Trees,
    store_dim: usize,
    keyframes: Vec<SemanticKeyframe>,
    staged: &mut Staged,
) -> Result<usize, StoreError> {
    let dim = if store_dim == 0 {
        keyframes.first().map_or(0, |k| k.features.descriptor.len())
    } else {
        store_dim
    };
    for kf in &keyframes {
        let found = kf.features.descriptor.len();
        if found != dim {
            return Err(StoreError::DimensionMismatch {
                expected: dim,
                found,
            });
        }
    }
    let mut seen = HashSet::new();
    for kf in keyframes {
        let key = encode_key(&kf.key);
        if !seen.insert(key.clone()) || trees.keyframes.contains_key(&key)? {
            staged.outcome.replaced += 1;
        } else {
            staged.added += 1;
            *staged
                .added_by_robot
                .entry(kf.key.robot_id.clone())
                .or_default() += 1;
        }
        staged.batch.insert(key.clone(), encode_record(&kf));
        staged.keys.push(key);
        staged.changes.push(IndexChange::Upsert(kf));
    }
    Ok(dim)
}

/// Removes the listed keyframes of a session that are stored.
pub(super) fn erase(
    trees: &Trees,
    session: &SessionKey,
    keyframe_ids: Vec<u64>,
    staged: &mut Staged,
) -> Result<(), StoreError> {
    let mut seen = HashSet::new();
    for keyframe_id in keyframe_ids {
        let key = session.keyframe(keyframe_id);
        let bytes = encode_key(&key);
        if seen.insert(keyframe_id) && trees.keyframes.contains_key(&bytes)? {
            staged.remove(bytes, key);
        }
    }
    Ok(())
}

/// Removes every keyframe of a session.
pub(super) fn reset_session(
    trees: &Trees,
    session: &SessionKey,
    staged: &mut Staged,
) -> Result<(), StoreError> {
    for item in trees
        .keyframes
        .scan_prefix(codec::session_prefix(session))
        .keys()
    {
        let bytes = item?;
        let key = corrupt_key(&bytes)?;
        staged.remove(bytes.to_vec(), key);
    }
    Ok(())
}

/// Removes every keyframe of one map of a session.
pub(super) fn reset_map(
    trees: &Trees,
    map: &MapKey,
    staged: &mut Staged,
) -> Result<(), StoreError> {
    for item in trees
        .keyframes
        .scan_prefix(codec::session_prefix(&map.session))
    {
        let (bytes, value) = item?;
        let record = decode(&bytes, &value)?;
        if record.map_id == map.map_id {
            staged.remove(bytes.to_vec(), record.key);
        }
    }
    Ok(())
}

/// Moves stored keyframes to new poses (and maps); ids not stored are
/// reported missing.
pub(super) fn pose_updates(
    trees: &Trees,
    session: &SessionKey,
    updates: Vec<PoseUpdate>,
    staged: &mut Staged,
) -> Result<(), StoreError> {
    for PoseUpdate {
        keyframe_id,
        pose,
        map_id,
    } in updates
    {
        let key = session.keyframe(keyframe_id);
        let bytes = encode_key(&key);
        let Some(value) = trees.keyframes.get(&bytes)? else {
            staged.outcome.missing.push(keyframe_id);
            continue;
        };
        let mut record = decode(&bytes, &value)?;
        record.pose = pose;
        if let Some(map_id) = map_id {
            record.map_id = map_id;
        }
        staged.batch.insert(bytes.clone(), encode_record(&record));
        staged.keys.push(bytes);
        staged.outcome.affected += 1;
        staged.changes.push(IndexChange::Move(key, pose, map_id));
    }
    Ok(())
}

fn decode(key: &[u8], value: &[u8]) -> Result<SemanticKeyframe, StoreError> {
    decode_record(value).map_err(|source| StoreError::Corrupt {
        key: key.to_vec(),
        source,
    })
}

fn corrupt_key(bytes: &[u8]) -> Result<KeyframeKey, StoreError> {
    codec::decode_key(bytes).map_err(|source| StoreError::Corrupt {
        key: bytes.to_vec(),
        source,
    })
}
