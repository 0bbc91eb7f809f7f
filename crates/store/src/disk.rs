//! Free space on the disk that holds the store, kept above a reserve.
//!
//! sled does not survive running out of space: a flush that hits ENOSPC
//! waits forever for a write that will never finish (sled 0.34), so the
//! writer, and with it every acknowledged-write path, would hang. The store
//! therefore never lets sled get there: before each group of changes, and
//! before each index snapshot, it checks the free space (one `statvfs`) and
//! refuses what would eat into `min_free_bytes` with a clean error. The
//! reserve must exceed one group's worth of writes (a few messages of at
//! most `server.max_message_bytes` each) plus sled's log segments.

use std::path::{Path, PathBuf};

/// Default of [`crate::StoreOptions::min_free_bytes`]: 256 MiB.
pub const DEFAULT_MIN_FREE_BYTES: u64 = 256 << 20;

/// The free-space check of one store directory.
#[derive(Debug, Clone)]
pub struct DiskGuard {
    dir: PathBuf,
    reserve: u64,
}

/// Space was short: what was free, and what is kept in reserve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Short {
    /// Bytes available to the store's user.
    pub available: u64,
    /// Bytes kept free.
    pub reserve: u64,
}

impl DiskGuard {
    /// A guard keeping `reserve` bytes free on the disk of `dir` (0: off).
    pub fn new(dir: &Path, reserve: u64) -> DiskGuard {
        DiskGuard {
            dir: dir.to_path_buf(),
            reserve,
        }
    }

    /// Bytes available on the disk, if the system says.
    pub fn available(&self) -> Option<u64> {
        let stats = rustix::fs::statvfs(&self.dir).ok()?;
        Some(stats.f_bavail.saturating_mul(stats.f_frsize))
    }

    /// `Err` if writing `bytes` more would leave less than the reserve.
    pub fn room_for(&self, bytes: u64) -> Result<(), Short> {
        if self.reserve == 0 {
            return Ok(());
        }
        match self.available() {
            Some(available) if available < self.reserve.saturating_add(bytes) => Err(Short {
                available,
                reserve: self.reserve,
            }),
            // Unknown (a file system without statvfs): nothing to go by.
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reserve_is_checked_against_the_real_free_space() {
        let dir = tempfile::tempdir().unwrap();
        let free = DiskGuard::new(dir.path(), 1).available().unwrap();
        assert!(free > 0);
        assert!(DiskGuard::new(dir.path(), 0).room_for(u64::MAX).is_ok());
        assert!(DiskGuard::new(dir.path(), 1).room_for(0).is_ok());
        let short = DiskGuard::new(dir.path(), free + (1 << 30))
            .room_for(0)
            .unwrap_err();
        assert_eq!(short.reserve, free + (1 << 30));
        assert!(DiskGuard::new(dir.path(), 1)
            .room_for(free + (1 << 30))
            .is_err());
    }
}
