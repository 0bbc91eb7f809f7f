//! The index snapshot: the whole in-memory index in one file beside the
//! sled tree, so that a restart loads it in one read instead of walking
//! and decoding every record in sled.
//!
//! sled stays the source of truth. A snapshot is only a cache of the index
//! as of one write sequence (see [`crate::journal`]); at open it is used
//! only if it names this store, is intact (CRC-32 over its body), and the
//! journal still holds every change after its sequence. Anything else and
//! the index is rebuilt from the tree, as without a snapshot.
//!
//! Layout (little-endian), version 1:
//!
//! | bytes | field |
//! | --- | --- |
//! | 8 | magic `HUMEMIX1` |
//! | 4 | snapshot format version |
//! | 16 | store id (from the store's meta tree) |
//! | 8 | write sequence the index reflects |
//! | 4 | descriptor dimension `d` |
//! | 8 | rows `N` |
//! | 8 | length of the row records, in bytes |
//! | 4 | CRC-32 of the descriptors |
//! | 4 | CRC-32 of the row records |
//! | `N·d·4` | descriptors, row-major f32: read straight into the matrix |
//! | rest | the rest of each keyframe, row by row, in postcard |
//!
//! Descriptors come first and raw, because they are nearly all the bytes
//! and are read into the index's matrix without decoding or copying. The
//! two sections have their own checksums so that two threads load them at
//! once: one reads the descriptors and encodes their one-byte codes, the
//! other decodes the rows and builds the index's tables.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use humem_core::engine::codes::CodeMatrix;
use humem_core::engine::matrix::DescriptorMatrix;
use humem_core::engine::row_file::RowFile;
use humem_core::index::{Index, IndexRestore, RestoreError};
use humem_core::keyframe::{
    Features, KeyframeKey, ObjectObservation, Pose, SceneClass, SemanticKeyframe,
};
use parking_lot::RwLock;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

#[cfg(target_endian = "big")]
compile_error!("the index snapshot stores f32 little-endian and is read without conversion");

/// File name of the snapshot in the data directory.
pub const FILE_NAME: &str = "index.snapshot";
const MAGIC: &[u8; 8] = b"HUMEMIX1";
const VERSION: u32 = 1;
const HEADER_BYTES: usize = 8 + 4 + 16 + 8 + 4 + 8 + 8 + 4 + 4;

/// Why a snapshot was not used.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    /// Reading or writing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The snapshot file.
        path: PathBuf,
        /// What the system reported.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a snapshot this build reads.
    #[error("not an index snapshot of version {VERSION}: {0}")]
    Format(&'static str),
    /// The snapshot was written for another store.
    #[error("the snapshot belongs to another store")]
    OtherStore,
    /// The descriptor dimension differs from the store's.
    #[error("the snapshot holds {found}-value descriptors, the store {expected}")]
    Dimension {
        /// The store's descriptor length.
        expected: usize,
        /// The snapshot's.
        found: usize,
    },
    /// The body does not match its checksum.
    #[error("checksum mismatch (the file is damaged)")]
    Checksum,
    /// A row record does not decode.
    #[error("row record does not decode: {0}")]
    Record(#[from] postcard::Error),
    /// The rows do not make an index.
    #[error("{0}")]
    Restore(#[from] RestoreError),
    /// The index's rows were reordered (grouped by map) between two of the
    /// snapshot's chunks, so the chunks may miss a keyframe; the writer
    /// does not group while a snapshot is written, so this is a guard.
    #[error(
        "the index's rows were reordered while the snapshot was written; it is taken again later"
    )]
    Regrouped,
}

/// Path of the snapshot in data directory `dir`.
pub fn path(dir: &Path) -> PathBuf {
    dir.join(FILE_NAME)
}

/// A snapshot's header: which store, which write sequence, what shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// The store the snapshot was taken of.
    pub store_id: u128,
    /// The last write sequence reflected in the snapshot.
    pub sequence: u64,
    /// Descriptor length.
    pub dim: usize,
    /// Keyframes in the snapshot.
    pub rows: usize,
}

/// Everything of a keyframe but its descriptor, as a snapshot row record.
#[derive(Serialize)]
struct RowOut<'a> {
    key: &'a KeyframeKey,
    frame_id: u64,
    timestamp: f64,
    map_id: u64,
    pose: &'a Pose,
    scene: &'a [SceneClass],
    objects: &'a [ObjectObservation],
    appearance: &'a [i8],
}

/// [`RowOut`], decoded.
#[derive(Deserialize)]
struct RowIn {
    key: KeyframeKey,
    frame_id: u64,
    timestamp: f64,
    map_id: u64,
    pose: Pose,
    scene: Vec<SceneClass>,
    objects: Vec<ObjectObservation>,
    appearance: Vec<i8>,
}

/// A snapshot written to its temporary file but not yet synced or in
/// place: [`Unpublished::publish`] finishes it, without the index.
#[derive(Debug)]
pub struct Unpublished {
    dir: PathBuf,
    temp: PathBuf,
    file: File,
    bytes: u64,
}

/// Rows copied per hold of the index's read lock: about 8 MB of
/// descriptors, a few milliseconds of copying.
const CHUNK_BYTES: usize = 8 << 20;

/// Writes the index as a snapshot of store `store_id` in `dir`, to a
/// temporary file; syncing and renaming it into place is
/// [`Unpublished::publish`], so a crash leaves the old snapshot or the new,
/// never half of one. Returns the snapshot with the write sequence it is
/// valid from (`applied` when it started).
///
/// The index is read in chunks, each under its own short hold of the read
/// lock and copied out before it is written, so the writer and the queries
/// never wait for the disk. Changes applied between chunks are in the
/// journal after the snapshot's sequence and are replayed over it at open.
/// The one thing replay could not restore is a keyframe that no change
/// touched but that moved: removing a row moves the last row into its
/// place. So chunks are taken from the last row down. A row only ever moves
/// down, from the last position, and the chunks move down too, so every
/// untouched keyframe is in some chunk; one that moved from a written chunk
/// into an unwritten one is written twice, and loading keeps one copy.
/// Grouping the rows by map ([`Index::group_tail`]) moves rows up as well:
/// the writer does not group while a snapshot is written, and a snapshot
/// that sees the [layout epoch](Index::layout_epoch) change fails
/// ([`SnapshotError::Regrouped`]) instead of missing a keyframe.
pub fn write(
    dir: &Path,
    store_id: u128,
    index: &RwLock<Index>,
    applied: &AtomicU64,
) -> Result<(Unpublished, u64), SnapshotError> {
    write_in_chunks(dir, store_id, index, applied, None, &mut || {})
}

/// [`write`], with `chunk_rows` rows per chunk (`None`: about
/// [`CHUNK_BYTES`] of descriptors) and `between` called after each chunk
/// is copied, with no lock held: tests change the store there.
pub(crate) fn write_in_chunks(
    dir: &Path,
    store_id: u128,
    index: &RwLock<Index>,
    applied: &AtomicU64,
    chunk_rows: Option<usize>,
    between: &mut dyn FnMut(),
) -> Result<(Unpublished, u64), SnapshotError> {
    let temp = dir.join(format!("{FILE_NAME}.tmp"));
    let records_temp = dir.join(format!("{FILE_NAME}.rows.tmp"));
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| SnapshotError::Io { path, source }
    };
    let file = File::create(&temp).map_err(io(&temp))?;
    let mut out = BufWriter::with_capacity(1 << 20, file);
    out.write_all(&[0; HEADER_BYTES]).map_err(io(&temp))?;
    let records_file = File::options()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(&records_temp)
        .map_err(io(&records_temp))?;
    let _ = std::fs::remove_file(&records_temp);
    let mut records_out = BufWriter::with_capacity(1 << 20, records_file);

    let (mut descriptors_crc, mut records_crc) =
        (crc32fast::Hasher::new(), crc32fast::Hasher::new());
    let (mut rows, mut records_len) = (0usize, 0u64);
    let mut dim;
    let mut sequence = None;
    let mut next = usize::MAX; // rows below this are still to be written
    let mut epoch = None;
    let (mut descriptors, mut records) = (Vec::<f32>::new(), Vec::<u8>::new());
    loop {
        descriptors.clear();
        records.clear();
        {
            let index = index.read();
            if *epoch.get_or_insert(index.layout_epoch()) != index.layout_epoch() {
                return Err(SnapshotError::Regrouped);
            }
            sequence.get_or_insert_with(|| applied.load(Ordering::Acquire));
            dim = index.dim();
            let hi = next.min(index.len());
            let per_chunk = chunk_rows.unwrap_or(CHUNK_BYTES / (4 * dim.max(1))).max(1);
            let lo = hi.saturating_sub(per_chunk);
            // One read of the chunk's rows (one call when they are in a
            // file), taken last row first like the records.
            let chunk = index.matrix().rows(lo, hi - lo);
            for rows_back in chunk.chunks_exact(dim.max(1)).rev() {
                descriptors.extend_from_slice(rows_back);
            }
            for row in (lo..hi).rev() {
                let meta = index.meta(row);
                records = postcard::to_extend(
                    &RowOut {
                        key: &meta.key,
                        frame_id: meta.frame_id,
                        timestamp: meta.timestamp,
                        map_id: meta.map_id,
                        pose: &meta.pose,
                        scene: &meta.scene,
                        objects: &meta.objects,
                        appearance: index.thumbnail(row),
                    },
                    records,
                )?;
            }
            rows += hi - lo;
            next = lo;
        }
        between();
        let bytes: &[u8] = bytemuck::cast_slice(&descriptors);
        descriptors_crc.update(bytes);
        out.write_all(bytes).map_err(io(&temp))?;
        records_crc.update(&records);
        records_out.write_all(&records).map_err(io(&records_temp))?;
        records_len += records.len() as u64;
        if next == 0 {
            break;
        }
    }
    let sequence = sequence.expect("at least one chunk");
    let mut records_file = records_out
        .into_inner()
        .map_err(|e| io(&records_temp)(e.into_error()))?;
    records_file
        .seek(SeekFrom::Start(0))
        .map_err(io(&records_temp))?;
    std::io::copy(&mut records_file, &mut out).map_err(io(&temp))?;

    let mut header = Vec::with_capacity(HEADER_BYTES);
    header.extend_from_slice(MAGIC);
    header.extend_from_slice(&VERSION.to_le_bytes());
    header.extend_from_slice(&store_id.to_le_bytes());
    header.extend_from_slice(&sequence.to_le_bytes());
    header.extend_from_slice(&(dim as u32).to_le_bytes());
    header.extend_from_slice(&(rows as u64).to_le_bytes());
    header.extend_from_slice(&records_len.to_le_bytes());
    header.extend_from_slice(&descriptors_crc.finalize().to_le_bytes());
    header.extend_from_slice(&records_crc.finalize().to_le_bytes());
    debug_assert_eq!(header.len(), HEADER_BYTES);
    let mut file = out.into_inner().map_err(|e| io(&temp)(e.into_error()))?;
    file.seek(SeekFrom::Start(0)).map_err(io(&temp))?;
    file.write_all(&header).map_err(io(&temp))?;
    let unpublished = Unpublished {
        dir: dir.to_path_buf(),
        temp,
        file,
        bytes: (HEADER_BYTES + rows * dim * 4) as u64 + records_len,
    };
    Ok((unpublished, sequence))
}

impl Unpublished {
    /// Syncs the snapshot and renames it over the old one; returns its
    /// size in bytes.
    pub fn publish(self) -> Result<u64, SnapshotError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| SnapshotError::Io { path, source }
        };
        self.file.sync_all().map_err(io(&self.temp))?;
        drop(self.file);
        let target = path(&self.dir);
        std::fs::rename(&self.temp, &target).map_err(io(&target))?;
        // The rename itself is durable once the directory is synced.
        File::open(&self.dir)
            .and_then(|d| d.sync_all())
            .map_err(io(&self.dir))?;
        Ok(self.bytes)
    }
}

/// Reads the snapshot in `dir`, if there is one: its header and the index
/// it holds. Checks magic, version, store id, dimension and checksum
/// before anything is decoded. A snapshot that `descriptors_to_file`
/// applies to leaves its descriptors in its own
/// file, as the base of a [`RowFile`] (changes go to that row file's
/// unnamed files in `dir`), instead of reading them into memory: opening
/// a large store neither holds them all in memory nor copies them.
pub fn read(
    dir: &Path,
    store_id: u128,
    dim: usize,
    descriptors_to_file: Option<crate::placement::FileRule>,
) -> Result<Option<(Header, Index)>, SnapshotError> {
    let file_path = path(dir);
    let io = |source| SnapshotError::Io {
        path: file_path.clone(),
        source,
    };
    let file = match File::open(&file_path) {
        Ok(file) => file,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(e)),
    };
    let file_len = file.metadata().map_err(io)?.len();
    let mut raw = [0u8; HEADER_BYTES];
    (&file)
        .read_exact(&mut raw)
        .map_err(|_| SnapshotError::Format("shorter than its header"))?;
    let mut fields = Fields(&raw[..]);
    if fields.take::<8>() != *MAGIC {
        return Err(SnapshotError::Format("bad magic"));
    }
    if u32::from_le_bytes(fields.take()) != VERSION {
        return Err(SnapshotError::Format("unknown version"));
    }
    let header = Header {
        store_id: u128::from_le_bytes(fields.take()),
        sequence: u64::from_le_bytes(fields.take()),
        dim: u32::from_le_bytes(fields.take()) as usize,
        rows: u64::from_le_bytes(fields.take()) as usize,
    };
    let records_len = u64::from_le_bytes(fields.take());
    let descriptors_crc = u32::from_le_bytes(fields.take());
    let records_crc = u32::from_le_bytes(fields.take());
    if header.store_id != store_id {
        return Err(SnapshotError::OtherStore);
    }
    if dim != 0 && header.rows > 0 && header.dim != dim {
        return Err(SnapshotError::Dimension {
            expected: dim,
            found: header.dim,
        });
    }
    if header.rows > 0 && header.dim == 0 {
        return Err(SnapshotError::Format("rows without a dimension"));
    }
    let descriptor_bytes = (header.rows as u64)
        .checked_mul(header.dim as u64 * 4)
        .ok_or(SnapshotError::Format("impossible size"))?;
    if HEADER_BYTES as u64 + descriptor_bytes + records_len != file_len {
        return Err(SnapshotError::Format("length does not match its header"));
    }

    // The two sections load side by side, each from its own file offset.
    let records_at = HEADER_BYTES as u64 + descriptor_bytes;
    let (matrix, restore) = std::thread::scope(|scope| {
        let records = scope.spawn(|| -> Result<_, SnapshotError> {
            let mut bytes = vec![0u8; records_len as usize];
            read_at(&file, records_at, &mut bytes).map_err(io)?;
            if crc32fast::hash(&bytes) != records_crc {
                return Err(SnapshotError::Checksum);
            }
            decode_rows(&bytes, header.rows)
        });
        let matrix = (|| -> Result<_, SnapshotError> {
            if header.rows == 0 {
                return Ok(DescriptorMatrix::new(dim.max(header.dim)));
            }
            if descriptors_to_file.is_some_and(|rule| rule.applies(header.rows, header.dim)) {
                // The rows stay where they are: read once for the checksum
                // and the codes, then served from this file's descriptor
                // section, which a later snapshot's rename does not touch.
                let mut codes = CodeMatrix::new(header.dim);
                let mut crc = crc32fast::Hasher::new();
                let mut block = vec![0f32; STREAM_ROWS.min(header.rows) * header.dim];
                for first in (0..header.rows).step_by(STREAM_ROWS) {
                    let rows = STREAM_ROWS.min(header.rows - first);
                    let block = &mut block[..rows * header.dim];
                    let at = HEADER_BYTES as u64 + (first * header.dim * 4) as u64;
                    read_at(&file, at, bytemuck::cast_slice_mut(block)).map_err(io)?;
                    crc.update(bytemuck::cast_slice(block));
                    codes.extend(header.dim, block);
                }
                if crc.finalize() != descriptors_crc {
                    return Err(SnapshotError::Checksum);
                }
                let base = file.try_clone().map_err(io)?;
                let rows = RowFile::over(base, HEADER_BYTES as u64, header.rows, dir, header.dim)
                    .map_err(io)?;
                return Ok(DescriptorMatrix::from_row_file(header.dim, rows, codes));
            }
            let mut data = vec![0f32; header.rows * header.dim];
            read_at(
                &file,
                HEADER_BYTES as u64,
                bytemuck::cast_slice_mut(&mut data),
            )
            .map_err(io)?;
            if crc32fast::hash(bytemuck::cast_slice(&data)) != descriptors_crc {
                return Err(SnapshotError::Checksum);
            }
            Ok(DescriptorMatrix::from_rows(header.dim, data))
        })();
        let restore = records.join().expect("the snapshot's row decoder panicked");
        (matrix, restore)
    });
    Ok(Some((header, restore?.finish(matrix?)?)))
}

/// Rows read per call when the descriptors stay in the snapshot file.
const STREAM_ROWS: usize = 16_384;

/// Fills `buffer` from `file` at `offset`, leaving the file's own position
/// alone, so two threads can read one file.
fn read_at(file: &File, offset: u64, buffer: &mut [u8]) -> std::io::Result<()> {
    use std::os::unix::fs::FileExt;
    file.read_exact_at(buffer, offset)
}

/// Decodes `rows` row records into the index being restored.
fn decode_rows(mut bytes: &[u8], rows: usize) -> Result<IndexRestore, SnapshotError> {
    let mut restore = Index::restore(rows);
    for _ in 0..rows {
        let (row, tail) = postcard::take_from_bytes::<RowIn>(bytes)?;
        bytes = tail;
        restore.push(SemanticKeyframe {
            key: row.key,
            frame_id: row.frame_id,
            timestamp: row.timestamp,
            map_id: row.map_id,
            pose: row.pose,
            features: Features {
                descriptor: Vec::new(),
                scene: row.scene,
                objects: row.objects,
                appearance: row.appearance,
            },
        })?;
    }
    if !bytes.is_empty() {
        return Err(SnapshotError::Format("bytes after the last row"));
    }
    Ok(restore)
}

/// Removes the snapshot in `dir`, if any (it no longer matches the store).
pub fn remove(dir: &Path) {
    let _ = std::fs::remove_file(path(dir));
}

/// Reads fixed-size fields off the front of a header.
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let (head, tail) = self.0.split_at(N);
        self.0 = tail;
        head.try_into().expect("split at N")
    }
}
