//! Where a bag's messages come from: ROS 2 bags in MCAP (through the
//! `mcap` crate's streaming reader) or in SQLite (`.db3`, through
//! `rusqlite`), as one file or a rosbag2 folder split into several, and ROS
//! 1 `.bag` files (through the `rosbag` crate).
//!
//! Every storage hands each message (topic, type, log time, bytes) to one
//! callback in time order within a file, so [`crate::bag`] reads all of
//! them with the same code and never learns which it had. A rosbag2
//! folder's files are read in the order its `metadata.yaml` lists them,
//! which is the order they were recorded (`drive_10.db3` after
//! `drive_9.db3`, not before `drive_2.db3`).

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::error::RecordingError;
use crate::extraction::Format;

/// One message of a bag.
pub(crate) struct BagMessage<'a> {
    pub(crate) topic: &'a str,
    /// The type without `/msg/`: `sensor_msgs/Image`.
    pub(crate) datatype: &'a str,
    /// Seconds.
    pub(crate) log_time: f64,
    pub(crate) data: &'a [u8],
}

/// `sensor_msgs/msg/Image` → `sensor_msgs/Image`.
fn ros1_name(datatype: &str) -> String {
    datatype.replacen("/msg/", "/", 1)
}

/// Calls `f` on every message of the bag at `path`, file by file, in
/// each file's order.
pub(crate) fn for_each_message(
    path: &Path,
    format: Format,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    match format {
        Format::Ros1Bag => ros1_messages(path, f),
        Format::Ros2Sqlite => {
            for file in rosbag2_files(path, "db3")? {
                sqlite_messages(&file, f)?;
            }
            Ok(())
        }
        _ => {
            for file in rosbag2_files(path, "mcap")? {
                mcap_messages(&file, f)?;
            }
            Ok(())
        }
    }
}

/// The parts of a rosbag2 folder's `metadata.yaml` read here.
#[derive(Debug, Default, serde::Deserialize)]
struct Rosbag2Metadata {
    rosbag2_bagfile_information: Rosbag2Information,
}

#[derive(Debug, Default, serde::Deserialize)]
#[serde(default)]
struct Rosbag2Information {
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    compression_format: String,
    compression_mode: String,
}

/// A rosbag2 folder's `metadata.yaml`, or `None` where it has none.
fn rosbag2_metadata(folder: &Path) -> Result<Option<Rosbag2Information>, RecordingError> {
    let path = folder.join("metadata.yaml");
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(RecordingError::io(&path))?;
    let metadata: Rosbag2Metadata =
        serde_yaml_ng::from_str(&text).map_err(|e| RecordingError::Damaged {
            path: path.clone(),
            reason: format!("not a rosbag2 metadata.yaml: {e}"),
        })?;
    Ok(Some(metadata.rosbag2_bagfile_information))
}

/// Which ROS 2 storage a rosbag2 folder holds: its `metadata.yaml`'s
/// `storage_identifier`, else the files in it.
pub(crate) fn rosbag2_format(folder: &Path) -> Result<Format, RecordingError> {
    if let Some(info) = rosbag2_metadata(folder)? {
        match info.storage_identifier.as_str() {
            "sqlite3" => return Ok(Format::Ros2Sqlite),
            "mcap" => return Ok(Format::Ros2Mcap),
            _ => {}
        }
    }
    let has = |ext: &str| {
        std::fs::read_dir(folder).is_ok_and(|entries| {
            entries
                .flatten()
                .any(|e| e.path().extension().is_some_and(|e| e == ext))
        })
    };
    Ok(if has("db3") && !has("mcap") {
        Format::Ros2Sqlite
    } else {
        Format::Ros2Mcap
    })
}

/// The trailing number of a split file's stem (`drive_12` → 12), to order
/// split files without a `metadata.yaml`.
fn split_number(path: &Path) -> u64 {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let digits = stem.len() - stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    stem[stem.len() - digits..].parse().unwrap_or(0)
}

/// The storage files of a bag (`ext`: `mcap`, `db3`): the file itself, or a
/// rosbag2 folder's files in recording order (its `metadata.yaml`'s list,
/// else by their split number).
fn rosbag2_files(path: &Path, ext: &str) -> Result<Vec<PathBuf>, RecordingError> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let unknown = |reason: String| RecordingError::UnknownFormat {
        path: path.to_path_buf(),
        reason,
    };
    if let Some(info) = rosbag2_metadata(path)? {
        if !info.compression_format.is_empty() || !info.compression_mode.is_empty() {
            return Err(unknown(format!(
                "a rosbag2 folder compressed with {} per {}; HuMem reads uncompressed storage:                  `ros2 bag convert` writes one",
                info.compression_format,
                info.compression_mode.to_ascii_lowercase()
            )));
        }
        if !info.relative_file_paths.is_empty() {
            let files: Vec<PathBuf> = info
                .relative_file_paths
                .iter()
                .map(|f| path.join(f))
                .collect();
            if let Some(missing) = files.iter().find(|f| !f.is_file()) {
                return Err(unknown(format!(
                    "its metadata.yaml lists {}, which is not there",
                    missing.display()
                )));
            }
            return Ok(files);
        }
    }
    let mut files = Vec::new();
    for entry in std::fs::read_dir(path).map_err(RecordingError::io(path))? {
        let entry = entry.map_err(RecordingError::io(path))?.path();
        if entry.extension().is_some_and(|e| e == ext) {
            files.push(entry);
        }
    }
    files.sort_by_key(|f| (split_number(f), f.clone()));
    if files.is_empty() {
        return Err(unknown(format!("a rosbag2 folder without .{ext} files")));
    }
    Ok(files)
}

/// Reads one rosbag2 SQLite file: its `topics` table, then its `messages`
/// in time order.
fn sqlite_messages(
    path: &Path,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    use rusqlite::{Connection, OpenFlags};
    let damaged = |e: rusqlite::Error| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason: format!("not a readable rosbag2 SQLite file: {e}"),
    };
    let db = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(damaged)?;
    let mut topics: HashMap<i64, (String, String, String)> = HashMap::new();
    let mut statement = db
        .prepare("SELECT id, name, type, serialization_format FROM topics")
        .map_err(damaged)?;
    let mut rows = statement.query([]).map_err(damaged)?;
    while let Some(row) = rows.next().map_err(damaged)? {
        let datatype: String = row.get(2).map_err(damaged)?;
        topics.insert(
            row.get(0).map_err(damaged)?,
            (
                row.get(1).map_err(damaged)?,
                ros1_name(&datatype),
                row.get(3).map_err(damaged)?,
            ),
        );
    }
    let mut statement = db
        .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(damaged)?;
    let mut rows = statement.query([]).map_err(damaged)?;
    while let Some(row) = rows.next().map_err(damaged)? {
        let topic_id: i64 = row.get(0).map_err(damaged)?;
        let Some((topic, datatype, encoding)) = topics.get(&topic_id) else {
            return Err(RecordingError::Damaged {
                path: path.to_path_buf(),
                reason: format!("a message of topic id {topic_id}, which the topics table lacks"),
            });
        };
        if encoding != "cdr" {
            continue;
        }
        let timestamp: i64 = row.get(1).map_err(damaged)?;
        let data =
            row.get_ref(2)
                .map_err(damaged)?
                .as_blob()
                .map_err(|e| RecordingError::Damaged {
                    path: path.to_path_buf(),
                    reason: format!("a message of {topic} whose data is not a blob: {e}"),
                })?;
        f(BagMessage {
            topic,
            datatype,
            log_time: timestamp as f64 * 1e-9,
            data,
        })?;
    }
    Ok(())
}

fn mcap_messages(
    path: &Path,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    use mcap::records::Record;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
    let damaged = |reason: String| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason,
    };
    let mut file = std::fs::File::open(path).map_err(RecordingError::io(path))?;
    let mut reader = LinearReader::new();
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut channels: HashMap<u16, (String, String, String)> = HashMap::new();
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| damaged(e.to_string()))? {
            LinearReadEvent::ReadRequest(need) => {
                let read = file
                    .read(reader.insert(need))
                    .map_err(RecordingError::io(path))?;
                reader.notify_read(read);
            }
            LinearReadEvent::Record { opcode, data } => {
                match mcap::parse_record(opcode, data).map_err(|e| damaged(e.to_string()))? {
                    Record::Schema { header, .. } => {
                        schemas.insert(header.id, ros1_name(&header.name));
                    }
                    Record::Channel(channel) => {
                        let datatype = schemas.get(&channel.schema_id).cloned().unwrap_or_default();
                        channels.insert(
                            channel.id,
                            (channel.topic, datatype, channel.message_encoding),
                        );
                    }
                    Record::Message { header, data } => {
                        let Some((topic, datatype, encoding)) = channels.get(&header.channel_id)
                        else {
                            return Err(damaged(format!(
                                "a message on channel {} that no channel record announced",
                                header.channel_id
                            )));
                        };
                        if encoding != "cdr" {
                            continue;
                        }
                        f(BagMessage {
                            topic,
                            datatype,
                            log_time: header.log_time as f64 * 1e-9,
                            data: &data,
                        })?;
                    }
                    _ => {}
                }
            }
        }
    }
    Ok(())
}

fn ros1_messages(
    path: &Path,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    use rosbag::{ChunkRecord, MessageRecord, RosBag};
    let damaged = |reason: String| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason,
    };
    check_ros1_index(path)?;
    let bag = RosBag::new(path).map_err(|e| damaged(e.to_string()))?;
    let mut connections: HashMap<u32, (String, String)> = HashMap::new();
    for record in bag.chunk_records() {
        let ChunkRecord::Chunk(chunk) = record.map_err(|e| damaged(e.to_string()))? else {
            continue;
        };
        for message in chunk.messages() {
            match message.map_err(|e| damaged(e.to_string()))? {
                MessageRecord::Connection(c) => {
                    connections.insert(c.id, (c.topic.to_string(), c.tp.to_string()));
                }
                MessageRecord::MessageData(m) => {
                    let Some((topic, datatype)) = connections.get(&m.conn_id) else {
                        return Err(damaged(format!(
                            "a message on connection {} that no connection record announced",
                            m.conn_id
                        )));
                    };
                    // Bag time: seconds in the low 32 bits, nanoseconds above.
                    let log_time = (m.time & 0xffff_ffff) as f64 + (m.time >> 32) as f64 * 1e-9;
                    f(BagMessage {
                        topic,
                        datatype,
                        log_time,
                        data: m.data,
                    })?;
                }
            }
        }
    }
    Ok(())
}

/// Checks that a ROS 1 bag's index lies within the file: a bag cut short
/// (a copy interrupted, a recorder killed) has lost it, and the `rosbag`
/// crate would index past the end of its mapping.
fn check_ros1_index(path: &Path) -> Result<(), RecordingError> {
    let damaged = |reason: &str| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    let mut file = std::fs::File::open(path).map_err(RecordingError::io(path))?;
    let len = file.metadata().map_err(RecordingError::io(path))?.len();
    let mut head = vec![0u8; 4096.min(len as usize)];
    file.read_exact(&mut head)
        .map_err(RecordingError::io(path))?;
    const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
    let Some(rest) = head.strip_prefix(MAGIC) else {
        return Err(damaged("not a ROS 1 bag (no #ROSBAG V2.0 line)"));
    };
    // The bag header record: its header's length, then `len name=value`
    // fields; `index_pos` is where the index starts.
    let u32_at = |b: &[u8], at: usize| {
        b.get(at..at + 4)
            .map(|v| u32::from_le_bytes(v.try_into().expect("4")) as usize)
    };
    let header_len = u32_at(rest, 0).ok_or_else(|| damaged("cut inside its header"))?;
    let header = rest
        .get(4..4 + header_len)
        .ok_or_else(|| damaged("cut inside its header"))?;
    let mut at = 0;
    while let Some(field_len) = u32_at(header, at) {
        let field = header
            .get(at + 4..at + 4 + field_len)
            .ok_or_else(|| damaged("a bad header field"))?;
        if let Some(value) = field.strip_prefix(b"index_pos=") {
            let index_pos =
                u64::from_le_bytes(value.try_into().map_err(|_| damaged("a bad index_pos"))?);
            if index_pos == 0 || index_pos >= len {
                return Err(damaged(&format!(
                    "truncated or never closed: its index starts at byte {index_pos} of {len} \
                     (`rosbag reindex` can rebuild it)"
                )));
            }
            return Ok(());
        }
        at += 4 + field_len;
    }
    Err(damaged("its header has no index_pos"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_files_come_in_recording_order() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["drive_10.db3", "drive_2.db3", "drive_0.db3", "notes.txt"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let names = |files: Vec<PathBuf>| -> Vec<String> {
            files
                .iter()
                .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
                .collect()
        };
        // Without a metadata.yaml: by the split number, not the name.
        let files = rosbag2_files(dir.path(), "db3").unwrap();
        assert_eq!(names(files), ["drive_0.db3", "drive_2.db3", "drive_10.db3"]);
        assert_eq!(rosbag2_format(dir.path()).unwrap(), Format::Ros2Sqlite);
        // With one: its list, which must name files that are there.
        let metadata = dir.path().join("metadata.yaml");
        std::fs::write(
            &metadata,
            "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  \
             relative_file_paths:\n    - drive_2.db3\n    - drive_0.db3\n",
        )
        .unwrap();
        let files = rosbag2_files(dir.path(), "db3").unwrap();
        assert_eq!(names(files), ["drive_2.db3", "drive_0.db3"]);
        std::fs::write(
            &metadata,
            "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  \
             relative_file_paths: [drive_1.db3]\n",
        )
        .unwrap();
        let err = rosbag2_files(dir.path(), "db3").unwrap_err().to_string();
        assert!(
            err.contains("lists") && err.contains("drive_1.db3"),
            "{err}"
        );
    }

    #[test]
    fn compressed_and_unreadable_storage_is_refused_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("drive_0.db3.zstd"), b"").unwrap();
        std::fs::write(
            dir.path().join("metadata.yaml"),
            "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  \
             compression_format: zstd\n  compression_mode: FILE\n  \
             relative_file_paths: [drive_0.db3.zstd]\n",
        )
        .unwrap();
        let err = rosbag2_files(dir.path(), "db3").unwrap_err().to_string();
        assert!(err.contains("compressed with zstd per file"), "{err}");
        assert!(err.contains("ros2 bag convert"), "{err}");

        let not_sqlite = dir.path().join("junk.db3");
        std::fs::write(&not_sqlite, b"this is not a database, just text").unwrap();
        let err = sqlite_messages(&not_sqlite, &mut |_| Ok(()))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("damaged bag") && err.contains("rosbag2 SQLite"),
            "{err}"
        );
    }
}
