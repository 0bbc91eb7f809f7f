//! The index's tables: the [`Index`] itself, with its row-aligned tables
//! and the accessors that read one row or one map.
//!
//! The other modules of the index each add one job's methods to it
//! (changes, eligibility, places and verdicts, restoring, grouping); they
//! share its fields through `pub(super)`, and this module needs none of
//! them, so the index's modules import in one direction only.

use rustc_hash::FxHashMap;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex};

use crate::engine::filter::RowGroup;
use crate::engine::graph::NeighbourGraph;
use crate::engine::matrix::DescriptorMatrix;
use crate::keyframe::{
    KeyframeKey, ObjectObservation, Pose, SceneClass, SemanticKeyframe, SessionKey,
};
use crate::row_ids::{Interner, RowIds};
use crate::verdict::VerdictBook;
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::feedback::VerdictParams;
use crate::vpr::operating_point::OperatingPoint;

/// A map: (robot, session, map id).
#[derive(
    Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub struct MapKey {
    /// The robot and session the map belongs to.
    pub session: SessionKey,
    /// Atlas map id within the session.
    pub map_id: u64,
}

/// Everything about a stored keyframe except its descriptor (which is a row
/// of the matrix).
#[derive(Debug, Clone)]
pub struct RowMeta {
    /// Identity of the keyframe.
    pub key: KeyframeKey,
    /// Source-frame id `f_i`.
    pub frame_id: u64,
    /// Timestamp `t_i` in seconds.
    pub timestamp: f64,
    /// Atlas map id `m_i` within the robot's session.
    pub map_id: u64,
    /// Camera pose in its map.
    pub pose: Pose,
    /// Top entries of the scene-class distribution, highest first.
    pub scene: Vec<SceneClass>,
    /// Stable objects seen in the keyframe, with their text.
    pub objects: Vec<ObjectObservation>,
}

/// `preds` entry of a row without a predecessor.
pub(super) const NO_ROW: u32 = u32::MAX;

impl RowMeta {
    /// The map this keyframe belongs to.
    pub fn map_key(&self) -> MapKey {
        MapKey {
            session: self.key.session(),
            map_id: self.map_id,
        }
    }

    /// Whether `other` is in the same map (robot, session and map id),
    /// without building either's [`MapKey`].
    pub fn same_map(&self, other: &RowMeta) -> bool {
        self.map_id == other.map_id
            && self.key.robot_id == other.key.robot_id
            && self.key.session_id == other.key.session_id
    }
}

/// The in-memory index.
#[derive(Debug)]
pub struct Index {
    pub(super) matrix: DescriptorMatrix,
    /// Appearance thumbnails, row-aligned with `matrix`.
    pub(super) appearance: AppearanceMatrix,
    pub(super) rows: Vec<RowMeta>,
    /// The integers eligibility reads, row-aligned (see [`crate::row_ids`]).
    pub(super) ids: Vec<RowIds>,
    /// Row of each row's predecessor in its track, or [`NO_ROW`]; a table
    /// of its own because the scan follows it for every row.
    pub(super) preds: Vec<u32>,
    /// Each row's null-sample tag (a hash of its key), row-aligned.
    pub(super) tags: Vec<u32>,
    pub(super) interner: Interner,
    pub(super) by_key: HashMap<KeyframeKey, usize>,
    /// Keyframe id → row, per map: the temporal tracks.
    pub(super) tracks: HashMap<MapKey, BTreeMap<u64, usize>>,
    /// Keyframe id → sample tag, per map, of the keyframes whose tag
    /// [`SAMPLED_MASK`](super::eligible::SAMPLED_MASK) keeps: a large
    /// map's null sample is drawn from these instead of its whole track.
    pub(super) sampled: HashMap<MapKey, BTreeMap<u64, u32>>,
    /// Number of keyframes each normalised OCR string appears in.
    pub(super) text_df: HashMap<String, u32>,
    /// SLAM's verdicts on pairs of stored keyframes; a verdict goes with
    /// either of its keyframes ([`Index::remove`]).
    pub(super) verdicts: VerdictBook,
    /// The operating point last estimated from `verdicts`
    /// ([`Index::operating_point`]); dropped when they change.
    pub(super) operating_point: Mutex<Option<CachedPoint>>,
    /// Each map's keyframe spacing once computed ([`Index::map_spacing`]);
    /// a map's entry is dropped when its track or a pose in it changes.
    pub(super) spacings: Mutex<HashMap<MapKey, f64>>,
    /// Each map's track as a path, kept as far as no change touched it
    /// ([`paths`](super::paths)).
    pub(super) paths: Mutex<HashMap<MapKey, TrackPath>>,
    /// Rows `0..grouped` were grouped by map; the rows after them were
    /// appended since (see [`grouping`]).
    pub(super) grouped: usize,
    /// Rows put out of their map's run since it was last grouped, per
    /// window of [`grouping::GROUP_WINDOW_ROWS`] grouped rows (see
    /// [`grouping`]).
    pub(super) displaced: Vec<u32>,
    /// Groupings so far ([`Index::layout_epoch`]).
    pub(super) layout_epoch: u64,
    /// Removals and groupings so far ([`Index::renumberings`]).
    pub(super) renumberings: u64,
    /// Passes that keep row numbers across releases of the lock and ask
    /// that rows not be grouped meanwhile ([`Index::hold_row_order`]).
    pub(super) row_order_holds: Arc<AtomicUsize>,
    /// Keyframes erased so far per session ([`Index::session_erasures`]);
    /// an entry is kept once made, so that the count never repeats.
    pub(super) erasures: HashMap<SessionKey, u64>,
    /// Changes to the rows so far: a planned grouping applies only to the
    /// index it was planned on.
    pub(super) changes: u64,
    /// The neighbour graph, where one is kept (see `neighbours`).
    pub(super) neighbours: Option<Neighbours>,
    /// Whether a neighbour graph was asked for (it starts with the first
    /// descriptor when the length was not known yet).
    pub(super) graph_wanted: bool,
    /// Whether stored keyframes wait to enter the graph until a caller adds
    /// them ([`Index::defer_graph_inserts`]) instead of entering it at once.
    pub(super) graph_deferred: bool,
    /// Length the graph shortens longer descriptors to (0: it does not;
    /// see [`Index::shorten_graph_rows`]).
    pub(super) graph_short: usize,
    /// Keyframes from which a map gets a neighbour graph of its own (0:
    /// none; see `map_graphs`).
    pub(super) map_graphs_from: usize,
    /// Maps' graphs saved earlier, offered to the maps' graphs the next
    /// neighbour graph starts ([`Index::offer_saved_map_graphs`]).
    pub(super) saved_map_graphs: HashMap<MapKey, NeighbourGraph>,
    /// Saved maps' graphs taken by their maps so far.
    pub(super) saved_map_graphs_taken: usize,
}

/// A map's track as a path: its keyframe ids ascending, the path driven
/// from the first to each, and the step into each (0 for the first). A
/// prefix of the track; `Index::track_path` completes it (see `paths`).
#[derive(Debug, Clone, Default)]
pub(super) struct TrackPath {
    pub(super) ids: Vec<u64>,
    pub(super) along: Vec<f64>,
    pub(super) steps: Vec<f64>,
}

impl TrackPath {
    /// Forgets keyframe `id` and every one after it: a change to `id`
    /// changes the path to each of them and to nothing before.
    pub(super) fn keep_before(&mut self, id: u64) {
        let keep = self.ids.partition_point(|&i| i < id);
        self.ids.truncate(keep);
        self.along.truncate(keep);
        self.steps.truncate(keep);
    }

    /// The path driven from the track's start to keyframe `id`.
    pub(super) fn at(&self, id: u64) -> Option<f64> {
        let i = self.ids.binary_search(&id).ok()?;
        Some(self.along[i])
    }

    /// The distances between consecutive keyframes of the track.
    pub(super) fn steps(&self) -> &[f64] {
        self.steps.get(1..).unwrap_or_default()
    }
}

/// The neighbour graph and the rows its keys name (see `neighbours`).
#[derive(Debug)]
pub(super) struct Neighbours {
    pub(super) graph: NeighbourGraph,
    /// Graph key of each keyframe in the graph → its row. Looked up for
    /// every keyframe a filtered walk visits; the keys are hashes
    /// already, so a fast hasher (Fx) does.
    pub(super) rows: FxHashMap<u64, u32>,
    /// Keyframes left out of the graph: their key's hash was another's,
    /// or the graph refused them. Only an exact pass finds them.
    pub(super) missing: usize,
    /// Keys of keyframes in `rows` that wait to enter the graph, oldest
    /// first (see [`Index::defer_graph_inserts`]); a search scores them
    /// exactly instead. A key may appear twice (stored again while
    /// waiting) or name an erased keyframe (then it is no longer in
    /// `rows` and is skipped).
    pub(super) waiting: Vec<u64>,
    /// Held while rows are added to the graph under a shared borrow of
    /// the index, and while the graph is saved, so the two never overlap.
    pub(super) adding: Mutex<()>,
    /// The graphs of the large maps, by their group (see `map_graphs`).
    pub(super) maps: HashMap<RowGroup, MapGraph>,
}

/// One large map's neighbour graph and the keys waiting to enter it (see
/// `map_graphs`).
#[derive(Debug)]
pub(super) struct MapGraph {
    /// The map, as saved graphs name it.
    pub(super) map: MapKey,
    pub(super) graph: NeighbourGraph,
    /// Graph keys of the map's keyframes that wait to enter it, oldest
    /// first; a key no longer in the store graph's `rows`, or now naming
    /// a row of another map, is skipped.
    pub(super) waiting: Vec<u64>,
}

/// An operating point and what it was estimated with.
#[derive(Debug)]
pub(super) struct CachedPoint {
    pub(super) params: VerdictParams,
    pub(super) base: f32,
    pub(super) at: f64,
    pub(super) point: OperatingPoint,
}

impl Index {
    /// An empty index for descriptors of length `dim` (0 while unknown).
    pub fn new(dim: usize) -> Self {
        Index {
            matrix: DescriptorMatrix::new(dim),
            appearance: AppearanceMatrix::default(),
            rows: Vec::new(),
            ids: Vec::new(),
            preds: Vec::new(),
            tags: Vec::new(),
            interner: Interner::default(),
            by_key: HashMap::new(),
            tracks: HashMap::new(),
            sampled: HashMap::new(),
            text_df: HashMap::new(),
            verdicts: VerdictBook::new(),
            operating_point: Mutex::new(None),
            spacings: Mutex::new(HashMap::new()),
            paths: Mutex::new(HashMap::new()),
            grouped: 0,
            displaced: Vec::new(),
            layout_epoch: 0,
            renumberings: 0,
            row_order_holds: Arc::default(),
            erasures: HashMap::new(),
            changes: 0,
            neighbours: None,
            graph_wanted: false,
            graph_deferred: false,
            graph_short: crate::engine::graph::SHORT_LENGTH,
            map_graphs_from: 0,
            saved_map_graphs: HashMap::new(),
            saved_map_graphs_taken: 0,
        }
    }

    /// Number of stored keyframes.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether no keyframe is stored.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Descriptor length of the stored keyframes (0 while unknown).
    pub fn dim(&self) -> usize {
        self.matrix.dim()
    }

    /// Row of the keyframe with `key`, if stored. Rows change when
    /// keyframes are removed, so do not keep one across changes.
    pub fn row_of(&self, key: &KeyframeKey) -> Option<usize> {
        self.by_key.get(key).copied()
    }

    /// Everything but the descriptor of a row. Panics if `row` is out of
    /// range.
    pub fn meta(&self, row: usize) -> &RowMeta {
        &self.rows[row]
    }

    /// Global descriptor of a row, [`Index::dim`] values (borrowed while
    /// the descriptors are in memory, read from their file otherwise).
    pub fn descriptor(&self, row: usize) -> std::borrow::Cow<'_, [f32]> {
        self.matrix.row(row)
    }

    /// Appearance thumbnail of a row; empty when the keyframe has none.
    pub fn thumbnail(&self, row: usize) -> &[i8] {
        self.appearance
            .row(row)
            .map_or(&[][..], |(thumbnail, _)| thumbnail)
    }

    /// The descriptor matrix, every row in row order.
    pub fn matrix(&self) -> &DescriptorMatrix {
        &self.matrix
    }

    /// Whether the f32 descriptors are in memory (see
    /// [`Index::move_descriptors_to_file`]).
    pub fn descriptors_in_memory(&self) -> bool {
        self.matrix.in_memory()
    }

    /// Moves the f32 descriptors to an unnamed file in `dir` and frees
    /// their memory (their codes stay; see
    /// [`DescriptorMatrix::move_to_file`]). Rows added later go to the file
    /// too, for as long as this index lives. Nothing changes while the
    /// dimension is unknown.
    pub fn move_descriptors_to_file(&mut self, dir: &std::path::Path) -> std::io::Result<()> {
        self.matrix.move_to_file(dir)
    }

    /// The whole keyframe of a row, as stored.
    pub fn keyframe(&self, row: usize) -> SemanticKeyframe {
        let meta = &self.rows[row];
        SemanticKeyframe {
            key: meta.key.clone(),
            frame_id: meta.frame_id,
            timestamp: meta.timestamp,
            map_id: meta.map_id,
            pose: meta.pose,
            features: crate::keyframe::Features {
                descriptor: self.matrix.row(row).to_vec(),
                scene: meta.scene.clone(),
                objects: meta.objects.clone(),
                appearance: self
                    .appearance
                    .row(row)
                    .map(|(thumbnail, _)| thumbnail.to_vec())
                    .unwrap_or_default(),
            },
        }
    }

    /// Rows of all keyframes of a session.
    pub fn session_rows(&self, session: &SessionKey) -> Vec<usize> {
        self.tracks
            .iter()
            .filter(|(map, _)| &map.session == session)
            .flat_map(|(_, track)| track.values().copied())
            .collect()
    }

    /// Rows of all keyframes of a map.
    pub fn map_rows(&self, map: &MapKey) -> Vec<usize> {
        self.tracks
            .get(map)
            .map(|track| track.values().copied().collect())
            .unwrap_or_default()
    }

    /// Keyframes stored for `robot_id`, over all its sessions and maps.
    pub fn robot_keyframes(&self, robot_id: &str) -> usize {
        self.tracks
            .iter()
            .filter(|(map, _)| map.session.robot_id == robot_id)
            .map(|(_, track)| track.len())
            .sum()
    }

    /// Keyframe counts per map, sorted by map.
    pub fn map_counts(&self) -> Vec<(MapKey, usize)> {
        let mut counts: Vec<_> = self
            .tracks
            .iter()
            .map(|(map, track)| (map.clone(), track.len()))
            .collect();
        counts.sort();
        counts
    }

    /// How many of `session`'s keyframes this index has erased since it
    /// was made (a replaced keyframe is not erased). It changes with every
    /// erasure, whether it came through this server or, in cluster mode,
    /// through another replica's write: perception names a session's
    /// camera stream with it, so that a read made before an erasure is
    /// not carried over to the keyframes after it.
    pub fn session_erasures(&self, session: &SessionKey) -> u64 {
        self.erasures.get(session).copied().unwrap_or(0)
    }

    /// The row of `row`'s predecessor in its track, if any.
    pub(super) fn prev(&self, row: usize) -> Option<usize> {
        let p = self.preds[row];
        (p != NO_ROW).then_some(p as usize)
    }
}
