//! Noticing that configuration files changed on disk, for the settings that
//! take effect without a restart (TLS certificates, the token file).
//!
//! Polls the files' contents four times a second (a revoked token must stop
//! working within a second) and compares them whole: a few kilobytes each
//! time, and it sees every kind of replacement (a rewrite, a
//! rename, the symlink swap of a Kubernetes Secret volume), which
//! modification times and sizes do not.

use std::path::PathBuf;
use std::time::Duration;

/// How often the files are read.
pub const CHECK_EVERY: Duration = Duration::from_millis(250);

/// What the files hold now (`None` for a file that cannot be read).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Snapshot(Vec<Option<Vec<u8>>>);

impl Snapshot {
    /// Reads `files`. Take it before loading them, and hand it to
    /// [`on_change`]: a change made while they load is then not missed.
    pub fn of(files: &[PathBuf]) -> Snapshot {
        Snapshot(files.iter().map(|path| std::fs::read(path).ok()).collect())
    }
}

/// Calls `changed` on a Tokio task whenever the contents of any of `files`
/// differ from the last look (starting from `seen`), until `changed`
/// returns `false`.
pub fn on_change(
    files: Vec<PathBuf>,
    mut seen: Snapshot,
    mut changed: impl FnMut() -> bool + Send + 'static,
) {
    tokio::spawn(async move {
        let mut interval = tokio::time::interval(CHECK_EVERY);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            interval.tick().await;
            let now = Snapshot::of(&files);
            if now == seen {
                continue;
            }
            seen = now;
            if !changed() {
                return;
            }
        }
    });
}
