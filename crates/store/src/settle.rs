//! Settling sled's log at open, before the writer takes inserts.
//!
//! After an open, sled marks every segment of its log inactive the first
//! time a write becomes stable, and for each one it counts the free and
//! inactive segments of the whole log (`SegmentAccountant::stabilize`,
//! sled 0.34): work that grows with the square of the log's segments.
//! On a 15 GB log (30 000 segments of 512 KiB) that is 1.5-3 s of a core,
//! under the lock every write takes when it starts a new segment, so it
//! held the first inserts after a restart, and the robots' queries behind
//! them, for as long.
//!
//! The open therefore writes a few segments' worth of scratch values and
//! flushes them: starting the next segment waits for that bookkeeping, so
//! the open ends after it instead of the first inserts. A log under
//! [`SETTLE_FROM_BYTES`] skips the scratch writes (its bookkeeping takes a
//! few milliseconds). The scratch tree is dropped at the end.

use std::time::Instant;

use crate::error::StoreError;
use crate::layout::META_OPENED;

/// Log size from which an open writes scratch segments (1 GiB: 2 048
/// segments, whose bookkeeping is ~10 ms).
pub(crate) const SETTLE_FROM_BYTES: u64 = 1 << 30;

/// Rounds of scratch writes: each fills more than a segment of sled's
/// default 512 KiB and is flushed, so each waits for the bookkeeping the
/// one before set going.
const ROUNDS: usize = 3;

/// Scratch values a round writes, each below sled's blob threshold (a
/// quarter of a segment), so that they go into the log itself.
const VALUES_PER_ROUND: usize = 10;
const VALUE_BYTES: usize = 64 * 1024;

/// Tree the scratch values go to; dropped before the open returns.
const SCRATCH_TREE: &[u8] = b"settle_scratch";

/// Records when the store was opened ([`META_OPENED`]), flushes, and on a
/// log of `from_bytes` or more ([`SETTLE_FROM_BYTES`] at open) writes and
/// flushes scratch segments until sled's bookkeeping after the open is
/// done (see the module doc).
pub(crate) fn settle_log(
    db: &sled::Db,
    meta: &sled::Tree,
    from_bytes: u64,
) -> Result<(), StoreError> {
    let started = Instant::now();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    meta.insert(META_OPENED, &now.to_be_bytes())?;
    db.flush()?;
    let log_bytes = db.size_on_disk()?;
    if log_bytes < from_bytes {
        return Ok(());
    }
    let scratch = db.open_tree(SCRATCH_TREE)?;
    let value = vec![0x5a_u8; VALUE_BYTES];
    for round in 0..ROUNDS {
        let round_started = Instant::now();
        for i in 0..VALUES_PER_ROUND {
            let key = ((round * VALUES_PER_ROUND + i) as u32).to_be_bytes();
            scratch.insert(key, value.as_slice())?;
        }
        db.flush()?;
        tracing::debug!(
            round,
            ms = round_started.elapsed().as_secs_f64() * 1e3,
            "settled a round of the log"
        );
    }
    drop(scratch);
    db.drop_tree(SCRATCH_TREE)?;
    db.flush()?;
    tracing::info!(
        log_bytes,
        ms = started.elapsed().as_secs_f64() * 1e3,
        "sled's log settled"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_db() -> (tempfile::TempDir, sled::Db, sled::Tree) {
        let dir = tempfile::tempdir().unwrap();
        let db = sled::Config::new().path(dir.path()).open().unwrap();
        let meta = db.open_tree(b"meta").unwrap();
        (dir, db, meta)
    }

    #[test]
    fn a_settled_log_keeps_what_it_held_and_no_scratch() {
        let (_dir, db, meta) = temp_db();
        let data = db.open_tree(b"data").unwrap();
        data.insert(b"k", b"v").unwrap();
        let before = db.size_on_disk().unwrap();
        settle_log(&db, &meta, 0).unwrap();
        assert!(
            db.size_on_disk().unwrap()
                > before + (ROUNDS * VALUES_PER_ROUND * VALUE_BYTES) as u64 / 2,
            "the scratch segments were written to the log"
        );
        assert!(!db.tree_names().iter().any(|n| n == SCRATCH_TREE));
        assert_eq!(data.get(b"k").unwrap().as_deref(), Some(&b"v"[..]));
        assert_eq!(meta.get(META_OPENED).unwrap().map(|v| v.len()), Some(8));
    }

    #[test]
    fn a_small_log_is_only_stamped() {
        let (_dir, db, meta) = temp_db();
        let before = db.size_on_disk().unwrap();
        settle_log(&db, &meta, SETTLE_FROM_BYTES).unwrap();
        assert!(db.size_on_disk().unwrap() < before + VALUE_BYTES as u64);
        assert!(!db.tree_names().iter().any(|n| n == SCRATCH_TREE));
        assert!(meta.get(META_OPENED).unwrap().is_some());
    }
}
