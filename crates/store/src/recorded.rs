//! What a store on disk records, read without opening it for writing:
//! its descriptor length ([`recorded_dim`]) and where it stands in a
//! replicated write log ([`recorded_log`]).
//!
//! Tools and the cluster's start-up ask these before (or instead of)
//! opening a store; they must neither create a store where there is none
//! nor change one, so they open sled only if its files are there and
//! read the meta tree alone.

use std::path::Path;

use crate::error::StoreError;
use crate::layout::{KEYFRAMES_TREE, META_DIM, META_LOG_POSITION, META_TREE};

/// The descriptor length the store in `dir` records, without creating or
/// changing a store: `None` where `dir` holds no store, or one whose length
/// is not fixed yet. Opens sled (which admits one process, so it fails
/// while a server runs on `dir`) and reads the meta tree only.
pub fn recorded_dim(dir: &Path) -> Result<Option<usize>, StoreError> {
    let Some(db) = open_existing(dir)? else {
        return Ok(None);
    };
    if !has_tree(&db, META_TREE) {
        return Ok(None);
    }
    let dim = db
        .open_tree(META_TREE)?
        .get(META_DIM)?
        .map(|v| u32::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 4])) as usize);
    Ok(dim.filter(|&d| d > 0))
}

/// Opens the sled database in `dir` if one is there (its configuration or
/// log file exists), without creating one.
fn open_existing(dir: &Path) -> Result<Option<sled::Db>, StoreError> {
    // sled keeps its configuration and log in these two files.
    if !dir.join("conf").is_file() && !dir.join("db").is_file() {
        return Ok(None);
    }
    sled::Config::new()
        .path(dir)
        .open()
        .map(Some)
        .map_err(|source| StoreError::Open {
            path: dir.display().to_string(),
            source,
        })
}

/// Whether `db` has a tree named `tree` (without creating it).
fn has_tree(db: &sled::Db, tree: &str) -> bool {
    db.tree_names().iter().any(|name| name == tree.as_bytes())
}

/// Where the store in `dir` stands in a replicated write log, read
/// without creating or changing a store.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecordedLog {
    /// The last entry applied (0: none, or no store).
    pub position: u64,
    /// Whether the store holds any keyframe.
    pub holds_keyframes: bool,
}

/// [`RecordedLog`] of the store in `dir`; like [`recorded_dim`], it fails
/// while a server runs on `dir`.
pub fn recorded_log(dir: &Path) -> Result<RecordedLog, StoreError> {
    let Some(db) = open_existing(dir)? else {
        return Ok(RecordedLog::default());
    };
    let has = |tree: &str| has_tree(&db, tree);
    let position = if has(META_TREE) {
        db.open_tree(META_TREE)?
            .get(META_LOG_POSITION)?
            .map_or(0, |v| {
                u64::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 8]))
            })
    } else {
        0
    };
    let holds_keyframes = has(KEYFRAMES_TREE) && !db.open_tree(KEYFRAMES_TREE)?.is_empty();
    Ok(RecordedLog {
        position,
        holds_keyframes,
    })
}
