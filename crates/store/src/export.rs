//! A whole store as one file, and a store made from one: how a cluster
//! replica publishes its store and how a new (or long-absent) replica
//! starts from it instead of from the first entry of the write log.
//!
//! The export is taken by the writer thread between two groups of
//! changes, so it holds exactly the changes up to the log position it
//! records, no half-applied group ([`crate::Store::export`]). It copies
//! sled's records byte for byte (keyframes, verdicts and their
//! by-candidate index), so a restored store answers exactly as the one
//! exported; the index and its journal are rebuilt at open, as after any
//! open without a current index snapshot (the neighbour graph, below, is
//! loaded rather than rebuilt).
//!
//! The file: the magic `HUMEMSNP`, a header (postcard, length-prefixed),
//! then records `[tree tag][u32 key length][key][u32 value length][value]`
//! and an end tag, so it streams in and out without holding the store in
//! memory. Where the store keeps a neighbour graph, the graph follows the
//! end tag (`[graph tag][u64 length][USearch's file]`), in step with the
//! records: a replica started from the export loads it instead of spending
//! minutes (at a million keyframes, most of an hour on two cores) building
//! it. Readers that predate the section stop at the end tag.

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::StoreError;
use crate::graph_file;
use crate::layout::{
    KEYFRAMES_TREE, META_DIM, META_FORMAT, META_LOG_POSITION, META_TREE, STORE_FORMAT,
    VERDICTS_BY_CANDIDATE_TREE, VERDICTS_TREE,
};

const MAGIC: &[u8; 8] = b"HUMEMSNP";
/// Version of this file's layout.
pub const EXPORT_FORMAT: u32 = 1;
const END: u8 = 0xff;
/// The neighbour graph's section, after [`END`].
const GRAPH: u8 = b'G';
/// Where a restore builds the new store, inside the store's directory.
const RESTORING: &str = "restoring.tmp";

/// What an export holds, written at its start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExportHeader {
    /// [`EXPORT_FORMAT`] of the writer.
    pub format: u32,
    /// The store layout its records are in ([`STORE_FORMAT`]).
    pub store_format: u32,
    /// Descriptor length (0: not fixed yet).
    pub dim: u32,
    /// The last write-log entry applied to the exported store.
    pub log_position: u64,
    /// Keyframes in it.
    pub keyframes: u64,
    /// Verdicts in it.
    pub verdicts: u64,
}

/// The trees an export carries, by tag.
pub(crate) const TREES: [(u8, &str); 3] = [
    (0, KEYFRAMES_TREE),
    (1, VERDICTS_TREE),
    (2, VERDICTS_BY_CANDIDATE_TREE),
];

fn io(context: &str, e: std::io::Error) -> StoreError {
    StoreError::Export(format!("{context}: {e}"))
}

/// A read error; the end of the file in the middle of a record is named.
fn read_error(what: &str, e: std::io::Error) -> StoreError {
    if e.kind() == std::io::ErrorKind::UnexpectedEof {
        StoreError::Export(format!("the export is cut short (reading {what})"))
    } else {
        io(&format!("reading {what}"), e)
    }
}

/// Writes `header` and every record of `trees` (tag, tree) to `out`,
/// then the neighbour graph saved at `graph`, if any.
pub(crate) fn write(
    header: ExportHeader,
    trees: &[(u8, &sled::Tree)],
    graph: Option<&Path>,
    out: impl Write,
) -> Result<(), StoreError> {
    let mut out = BufWriter::new(out);
    let head = postcard::to_allocvec(&header).map_err(|e| StoreError::Export(e.to_string()))?;
    let write = |out: &mut BufWriter<_>, bytes: &[u8]| {
        out.write_all(bytes)
            .map_err(|e| io("writing the export", e))
    };
    write(&mut out, MAGIC)?;
    write(&mut out, &(head.len() as u32).to_le_bytes())?;
    write(&mut out, &head)?;
    for (tag, tree) in trees {
        for item in tree.iter() {
            let (key, value) = item?;
            write(&mut out, &[*tag])?;
            write(&mut out, &(key.len() as u32).to_le_bytes())?;
            write(&mut out, &key)?;
            write(&mut out, &(value.len() as u32).to_le_bytes())?;
            write(&mut out, &value)?;
        }
    }
    write(&mut out, &[END])?;
    if let Some(graph) = graph {
        let mut file = std::fs::File::open(graph).map_err(|e| io("reading the graph", e))?;
        let len = file
            .metadata()
            .map_err(|e| io("reading the graph", e))?
            .len();
        write(&mut out, &[GRAPH])?;
        write(&mut out, &len.to_le_bytes())?;
        let copied = std::io::copy(&mut file, &mut out).map_err(|e| io("writing the graph", e))?;
        if copied != len {
            return Err(StoreError::Export(format!(
                "the graph file changed while it was exported ({copied} of {len} bytes)"
            )));
        }
    }
    out.flush().map_err(|e| io("writing the export", e))
}

/// Reads what follows the records' end tag: nothing, or the neighbour
/// graph, which is written to `graph`.
fn read_graph(input: &mut impl Read, graph: &Path) -> Result<bool, StoreError> {
    let mut tag = [0u8; 1];
    match input.read(&mut tag) {
        Ok(0) => return Ok(false),
        Ok(_) => {}
        Err(e) => return Err(io("reading past the records", e)),
    }
    if tag[0] != GRAPH {
        return Err(StoreError::Export(format!(
            "unknown section {} after the records",
            tag[0]
        )));
    }
    let mut len = [0u8; 8];
    input
        .read_exact(&mut len)
        .map_err(|e| read_error("the graph's length", e))?;
    let len = u64::from_le_bytes(len);
    let mut out = BufWriter::new(
        std::fs::File::create(graph).map_err(|e| io(&format!("{}", graph.display()), e))?,
    );
    let copied = std::io::copy(&mut input.take(len), &mut out)
        .map_err(|e| io(&format!("writing {}", graph.display()), e))?;
    if copied != len {
        return Err(StoreError::Export(
            "the export is cut short (reading the graph)".into(),
        ));
    }
    out.flush()
        .map_err(|e| io(&format!("writing {}", graph.display()), e))?;
    Ok(true)
}

/// Reads an export's header.
fn read_header(input: &mut impl Read) -> Result<ExportHeader, StoreError> {
    let mut magic = [0u8; 8];
    input
        .read_exact(&mut magic)
        .map_err(|e| read_error("the export's start", e))?;
    if &magic != MAGIC {
        return Err(StoreError::Export("not a HuMem store export".into()));
    }
    let head = read_bytes(input, "the export's header")?;
    let header: ExportHeader =
        postcard::from_bytes(&head).map_err(|e| StoreError::Export(format!("header: {e}")))?;
    if header.format != EXPORT_FORMAT || header.store_format != STORE_FORMAT {
        return Err(StoreError::Export(format!(
            "export format {} of store format {}; this build reads {EXPORT_FORMAT} of {STORE_FORMAT}",
            header.format, header.store_format
        )));
    }
    Ok(header)
}

fn read_bytes(input: &mut impl Read, what: &str) -> Result<Vec<u8>, StoreError> {
    let mut len = [0u8; 4];
    input
        .read_exact(&mut len)
        .map_err(|e| read_error(what, e))?;
    let mut bytes = vec![0u8; u32::from_le_bytes(len) as usize];
    input
        .read_exact(&mut bytes)
        .map_err(|e| read_error(what, e))?;
    Ok(bytes)
}

/// Makes the store in `dir` the one exported in `file`: whatever `dir`
/// held is replaced. The new store is built in a folder inside it and
/// moved into place only once complete and flushed; a restore cut short
/// leaves a store that has applied no log entry, which the replica restores
/// again at its next start. A neighbour graph the export carries is left
/// for the first open to load. No store may be open on `dir`.
pub fn restore(dir: &Path, file: &Path) -> Result<ExportHeader, StoreError> {
    std::fs::create_dir_all(dir).map_err(|e| io(&format!("{}", dir.display()), e))?;
    let building = dir.join(RESTORING);
    if building.exists() {
        std::fs::remove_dir_all(&building).map_err(|e| io("clearing an earlier restore", e))?;
    }
    let mut input = BufReader::new(
        std::fs::File::open(file).map_err(|e| io(&format!("{}", file.display()), e))?,
    );
    let header = read_header(&mut input)?;
    {
        let db = sled::Config::new()
            .path(&building)
            .open()
            .map_err(|source| StoreError::Open {
                path: building.display().to_string(),
                source,
            })?;
        let trees: Vec<(u8, sled::Tree)> = TREES
            .iter()
            .map(|(tag, name)| Ok((*tag, db.open_tree(name)?)))
            .collect::<Result<_, StoreError>>()?;
        loop {
            let mut tag = [0u8; 1];
            input
                .read_exact(&mut tag)
                .map_err(|e| read_error("a record's tree", e))?;
            if tag[0] == END {
                break;
            }
            let tree = trees
                .iter()
                .find(|(t, _)| *t == tag[0])
                .map(|(_, tree)| tree)
                .ok_or_else(|| StoreError::Export(format!("unknown tree tag {}", tag[0])))?;
            let key = read_bytes(&mut input, "a record's key")?;
            let value = read_bytes(&mut input, "a record's value")?;
            tree.insert(key, value)?;
        }
        let meta = db.open_tree(META_TREE)?;
        meta.insert(META_FORMAT, &STORE_FORMAT.to_be_bytes())?;
        if header.dim > 0 {
            meta.insert(META_DIM, &header.dim.to_be_bytes())?;
        }
        meta.insert(META_LOG_POSITION, &header.log_position.to_be_bytes())?;
        db.flush()?;
    }
    read_graph(&mut input, &graph_file::restored_path(&building))?;
    // The directory itself stays (it may be a mount point): its entries go,
    // the new ones move in.
    for entry in std::fs::read_dir(dir).map_err(|e| io("listing the old store", e))? {
        let path = entry.map_err(|e| io("listing the old store", e))?.path();
        // The new store, and a snapshot downloaded beside it.
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        if path == building || name.is_some_and(|n| n.starts_with("restoring")) {
            continue;
        }
        let removed = if path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        removed.map_err(|e| io(&format!("removing {}", path.display()), e))?;
    }
    for entry in std::fs::read_dir(&building).map_err(|e| io("listing the restored store", e))? {
        let path = entry
            .map_err(|e| io("listing the restored store", e))?
            .path();
        let name = path.file_name().expect("a directory entry has a name");
        std::fs::rename(&path, dir.join(name))
            .map_err(|e| io("moving the restored store in place", e))?;
    }
    std::fs::remove_dir(&building).map_err(|e| io("removing the restore's folder", e))?;
    Ok(header)
}
