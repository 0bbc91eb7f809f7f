//! The write journal: which keyframes each change touched, by write
//! sequence, so that an index snapshot can be brought up to date at open.
//!
//! Every change the writer applies gets the next sequence number, and its
//! journal entry (the sled keys it wrote or removed, and the store's
//! keyframe count after it) is written in the same sled transaction as the
//! change itself: sled never holds one without the other. At open, the
//! keys of the entries after the snapshot's sequence are read again from
//! the keyframes tree, which is the source of truth, so replay needs no
//! record of *what* changed, only *where*.
//!
//! Once a snapshot is safely on disk, the entries it covers are removed and
//! the meta tree's `journal_floor` records up to where. A snapshot older
//! than the floor can no longer be brought up to date and is not used.
//!
//! The meta tree also holds the store's random id, which a snapshot names,
//! so a snapshot is never applied to another store.

use std::collections::HashSet;
use std::hash::{BuildHasher, Hasher};

use serde::{Deserialize, Serialize};

use crate::error::StoreError;

/// Name of the journal's sled tree.
pub const TREE: &str = "journal";
const META_STORE_ID: &[u8] = b"store_id";
const META_FLOOR: &[u8] = b"journal_floor";

/// One change's journal entry.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Entry {
    /// Keyframes in the store after the change.
    pub keyframes: u64,
    /// sled keys of the keyframes the change wrote or removed.
    pub keys: Vec<Vec<u8>>,
}

/// The sled key of sequence `sequence`: big-endian, so entries sort by it.
pub fn key(sequence: u64) -> [u8; 8] {
    sequence.to_be_bytes()
}

/// What the journal holds after a snapshot's sequence.
#[derive(Debug, Default)]
pub struct Pending {
    /// Distinct keys touched after the snapshot, in first-touched order.
    pub keys: Vec<Vec<u8>>,
    /// Keyframe count after the last entry, if there is one.
    pub keyframes: Option<u64>,
}

/// The store's id, created (randomly) on first use.
pub fn store_id(meta: &sled::Tree) -> Result<u128, StoreError> {
    if let Some(bytes) = meta.get(META_STORE_ID)? {
        if let Ok(bytes) = <[u8; 16]>::try_from(bytes.as_ref()) {
            return Ok(u128::from_be_bytes(bytes));
        }
    }
    // std's hasher keys are seeded from the OS's random source: enough for
    // an identity that only has to differ between stores.
    let random = || {
        std::collections::hash_map::RandomState::new()
            .build_hasher()
            .finish()
    };
    let id = (u128::from(random()) << 64) | u128::from(random());
    meta.insert(META_STORE_ID, &id.to_be_bytes())?;
    Ok(id)
}

/// Entries up to the floor have been removed (a snapshot covers them).
pub fn floor(meta: &sled::Tree) -> Result<u64, StoreError> {
    Ok(meta
        .get(META_FLOOR)?
        .and_then(|v| <[u8; 8]>::try_from(v.as_ref()).ok())
        .map_or(0, u64::from_be_bytes))
}

/// The last sequence used: the newest entry, or the floor when the journal
/// is empty.
pub fn last_sequence(journal: &sled::Tree, meta: &sled::Tree) -> Result<u64, StoreError> {
    let newest = match journal.last()? {
        Some((key, _)) => sequence_of(&key)?,
        None => 0,
    };
    Ok(newest.max(floor(meta)?))
}

/// Keys touched after `sequence`, and the count after the last entry.
pub fn pending(journal: &sled::Tree, sequence: u64) -> Result<Pending, StoreError> {
    let mut pending = Pending::default();
    let mut seen = HashSet::new();
    for item in journal.range(key(sequence.saturating_add(1))..) {
        let (key, value) = item?;
        let entry: Entry = postcard::from_bytes(&value).map_err(|e| StoreError::Corrupt {
            key: key.to_vec(),
            source: e.into(),
        })?;
        pending.keyframes = Some(entry.keyframes);
        for k in entry.keys {
            if seen.insert(k.clone()) {
                pending.keys.push(k);
            }
        }
    }
    Ok(pending)
}

/// Removes the entries up to `sequence` (a snapshot on disk covers them)
/// and raises the floor to it. The floor is raised first: a crash in
/// between leaves old entries that nothing reads, never a gap.
pub fn truncate(journal: &sled::Tree, meta: &sled::Tree, sequence: u64) -> Result<(), StoreError> {
    if floor(meta)? >= sequence {
        return Ok(());
    }
    meta.insert(META_FLOOR, &sequence.to_be_bytes())?;
    let mut batch = sled::Batch::default();
    for item in journal.range(..=key(sequence)).keys() {
        batch.remove(item?);
    }
    journal.apply_batch(batch)?;
    Ok(())
}

fn sequence_of(key: &[u8]) -> Result<u64, StoreError> {
    <[u8; 8]>::try_from(key)
        .map(u64::from_be_bytes)
        .map_err(|_| StoreError::Corrupt {
            key: key.to_vec(),
            source: crate::codec::CodecError::BadKey("journal key is not 8 bytes"),
        })
}
