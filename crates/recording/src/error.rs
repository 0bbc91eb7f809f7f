//! Why a recording could not be read: [`RecordingError`], which names the
//! file, topic, message or line that is wrong.
//!
//! A leaf module: every other module returns it, so it depends on none of
//! them.

use std::path::{Path, PathBuf};

/// Why a recording could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The path is none of the recordings this crate reads.
    #[error("{path}: not a recording HuMem reads ({reason})")]
    UnknownFormat {
        /// The path.
        path: PathBuf,
        /// What was looked for.
        reason: String,
    },
    /// The bag itself is damaged (truncated, bad record).
    #[error("{path}: damaged bag: {reason}")]
    Damaged {
        /// The bag.
        path: PathBuf,
        /// What the reader found.
        reason: String,
    },
    /// A topic asked for is not in the bag, or none fits.
    #[error("{path}: {reason}; the bag's topics: {topics}")]
    Topic {
        /// The bag.
        path: PathBuf,
        /// What is missing or ambiguous.
        reason: String,
        /// Every topic with its type.
        topics: String,
    },
    /// A message that cannot be used.
    #[error("{path}: topic {topic}, message {index}: {reason}")]
    Message {
        /// The bag.
        path: PathBuf,
        /// Its topic.
        topic: String,
        /// 0-based index of the message on its topic.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// A line of a text file that cannot be used.
    #[error("{path}, line {line}: {reason}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Something else about the layout (missing folder, counts disagree).
    #[error("{path}: {reason}")]
    Layout {
        /// Where.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// No image has a pose within the tolerance.
    #[error("no image from {images} has a pose from {poses} within {tolerance} s ({detail})")]
    NoPose {
        /// Where the images came from.
        images: String,
        /// Where the poses came from.
        poses: String,
        /// The tolerance, seconds.
        tolerance: f64,
        /// The time spans, to see the mismatch.
        detail: String,
    },
}

impl RecordingError {
    pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
        move |source| RecordingError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}
