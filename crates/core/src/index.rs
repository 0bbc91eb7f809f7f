//! The in-memory search index over the stored keyframes.
//!
//! It is rebuilt from sled at start and kept in step with it by the writer.
//! Descriptors live in one contiguous row-major matrix, because SCAL is a
//! scan over all of them and is bound by memory bandwidth; everything else
//! about a keyframe lives in a row-aligned table. Erasing swaps the last row
//! into the hole, so rows stay dense.
//!
//! Each row also knows its predecessor: the keyframe before it (by keyframe
//! id) in the same robot, session and map, which is what SCAL's temporal
//! context compares. Predecessor links are maintained on every change so a
//! query never has to look them up in a tree.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::{Mutex, PoisonError};

use crate::keyframe::{
    KeyframeKey, ObjectObservation, Pose, SceneClass, SemanticKeyframe, SessionKey,
};
use crate::row_ids::{Eligibility, Interner, RowIds};
use crate::verdict::{Verdict, VerdictBook, VerificationKind};
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::eligibility::QueryContext;
use crate::vpr::feedback::{squared_distance, Place, VerdictParams};
use crate::vpr::operating_point::{OperatingPoint, Sample};
use crate::vpr::{self, DescriptorMatrix, KeyframeMemory};

mod grouping;
pub use grouping::{RowGrouping, GROUP_TAIL_ROWS, GROUP_WINDOW_ROWS, REGROUP_DISPLACED_ROWS};

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
const NO_ROW: u32 = u32::MAX;

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

/// Why [`IndexRestore`] could not rebuild an index.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RestoreError {
    /// More or fewer keyframes were given than announced or than the
    /// matrix has rows.
    #[error("{keyframes} keyframes for {rows} descriptor rows")]
    CountMismatch {
        /// Rows of the loaded matrix.
        rows: usize,
        /// Keyframes given (so far, when too many).
        keyframes: usize,
    },
}

/// An index being rebuilt from a snapshot (see [`Index::restore`]); row
/// `i` of the matrix given to [`IndexRestore::finish`] belongs to the
/// `i`-th keyframe pushed.
#[derive(Debug)]
pub struct IndexRestore {
    index: Index,
    expected: usize,
    /// Rows pushed so far, duplicates included.
    pushed: usize,
    /// Rows whose key an earlier row already had.
    duplicates: Vec<usize>,
}

impl IndexRestore {
    /// Adds the next row's keyframe; its descriptor field is ignored (the
    /// matrix row stands for it). A key seen before is skipped, with its
    /// matrix row: a snapshot taken while the store changed may hold a
    /// keyframe twice, and both copies are the same.
    pub fn push(&mut self, keyframe: SemanticKeyframe) -> Result<(), RestoreError> {
        if self.pushed >= self.expected {
            return Err(RestoreError::CountMismatch {
                rows: self.expected,
                keyframes: self.pushed + 1,
            });
        }
        self.pushed += 1;
        let index = &mut self.index;
        if index.by_key.contains_key(&keyframe.key) {
            self.duplicates.push(self.pushed - 1);
            return Ok(());
        }
        let row = index.rows.len();
        index.attach(row, keyframe);
        Ok(())
    }

    /// The rebuilt index: every row's keyframe joined with `matrix`, whose
    /// row `i` is the `i`-th keyframe pushed's descriptor.
    pub fn finish(self, matrix: DescriptorMatrix) -> Result<Index, RestoreError> {
        let mut index = self.index;
        if self.pushed != matrix.len() {
            return Err(RestoreError::CountMismatch {
                rows: matrix.len(),
                keyframes: self.pushed,
            });
        }
        index.matrix = if self.duplicates.is_empty() {
            matrix
        } else {
            matrix.without_rows(&self.duplicates)
        };
        Ok(index)
    }
}

/// The in-memory index.
#[derive(Debug)]
pub struct Index {
    matrix: DescriptorMatrix,
    /// Appearance thumbnails, row-aligned with `matrix`.
    appearance: AppearanceMatrix,
    rows: Vec<RowMeta>,
    /// The integers eligibility reads, row-aligned (see [`crate::row_ids`]).
    ids: Vec<RowIds>,
    /// Row of each row's predecessor in its track, or [`NO_ROW`]; a table
    /// of its own because the scan follows it for every row.
    preds: Vec<u32>,
    /// Each row's null-sample tag (a hash of its key), row-aligned.
    tags: Vec<u32>,
    interner: Interner,
    by_key: HashMap<KeyframeKey, usize>,
    /// Keyframe id → row, per map: the temporal tracks.
    tracks: HashMap<MapKey, BTreeMap<u64, usize>>,
    /// Number of keyframes each normalised OCR string appears in.
    text_df: HashMap<String, u32>,
    /// SLAM's verdicts on pairs of stored keyframes; a verdict goes with
    /// either of its keyframes ([`Index::remove`]).
    verdicts: VerdictBook,
    /// The operating point last estimated from `verdicts`
    /// ([`Index::operating_point`]); dropped when they change.
    operating_point: Mutex<Option<CachedPoint>>,
    /// Each map's keyframe spacing once computed ([`Index::map_spacing`]);
    /// a map's entry is dropped when its track or a pose in it changes.
    spacings: Mutex<HashMap<MapKey, f64>>,
    /// Rows `0..grouped` were grouped by map; the rows after them were
    /// appended since (see [`grouping`]).
    grouped: usize,
    /// Rows put out of their map's run since it was last grouped, per
    /// window of [`grouping::GROUP_WINDOW_ROWS`] grouped rows (see
    /// [`grouping`]).
    displaced: Vec<u32>,
    /// Groupings so far ([`Index::layout_epoch`]).
    layout_epoch: u64,
    /// Keyframes erased so far per session ([`Index::session_erasures`]);
    /// an entry is kept once made, so that the count never repeats.
    erasures: HashMap<SessionKey, u64>,
    /// Changes to the rows so far: a planned grouping applies only to the
    /// index it was planned on.
    changes: u64,
}

/// An operating point and what it was estimated with.
#[derive(Debug)]
struct CachedPoint {
    params: VerdictParams,
    base: f32,
    at: f64,
    point: OperatingPoint,
}

/// Seconds an estimated operating point is reused while no verdict
/// changes: the verdicts' weights decay over days, so a minute moves
/// nothing that matters, and a busy server estimates it once a minute
/// instead of once a query.
pub const OPERATING_POINT_REFRESH_S: f64 = 60.0;

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
            text_df: HashMap::new(),
            verdicts: VerdictBook::new(),
            operating_point: Mutex::new(None),
            spacings: Mutex::new(HashMap::new()),
            grouped: 0,
            displaced: Vec::new(),
            layout_epoch: 0,
            erasures: HashMap::new(),
            changes: 0,
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

    /// The eligibility rule of `context`, compiled for this index's rows:
    /// `test(row)` agrees with [`vpr::is_eligible`] on the row's keyframe.
    /// It names the rows of the maps the rule admits as its partition, so
    /// that a scan visits only those, when they are at most
    /// [`PARTITION_MAX_SHARE`] of the store.
    pub fn eligibility(&self, context: &QueryContext) -> RowEligibility<'_> {
        let rule = Eligibility::compile(context, &self.interner);
        let partition = self.partition(&rule);
        RowEligibility {
            rule,
            ids: &self.ids,
            partition,
        }
    }

    /// The rows of every map `rule` admits (scope and read access), sorted,
    /// or `None` when they are more than [`PARTITION_MAX_SHARE`] of the
    /// store. The tracks are the partition: every row is in its map's
    /// track, so counting costs one look per map, and gathering the rows
    /// one per admitted row.
    fn partition(&self, rule: &Eligibility) -> Option<Vec<usize>> {
        let admitted: Vec<&BTreeMap<u64, usize>> = self
            .tracks
            .values()
            .filter(|track| {
                track.values().next().is_some_and(|&row| {
                    let ids = &self.ids[row];
                    rule.admits_map(ids.robot, ids.session, ids.map_id)
                })
            })
            .collect();
        let count: usize = admitted.iter().map(|track| track.len()).sum();
        if count as f64 > PARTITION_MAX_SHARE * self.len() as f64 {
            return None;
        }
        let mut rows: Vec<usize> = admitted
            .into_iter()
            .flat_map(|track| track.values().copied())
            .collect();
        rows.sort_unstable();
        Some(rows)
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

    /// Starts rebuilding an index of `rows` keyframes from a snapshot:
    /// everything but the descriptors is added row by row with
    /// [`IndexRestore::push`], and the descriptor matrix, loaded on its
    /// own (so both can be loaded at once, and no descriptor is copied),
    /// joins them in [`IndexRestore::finish`].
    pub fn restore(rows: usize) -> IndexRestore {
        let mut index = Index::new(0);
        index.rows.reserve(rows);
        index.ids.reserve(rows);
        index.preds.reserve(rows);
        index.by_key.reserve(rows);
        IndexRestore {
            index,
            expected: rows,
            pushed: 0,
            duplicates: Vec::new(),
        }
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

    /// Stores a keyframe, replacing the one with the same key. Returns true if
    /// one was replaced. The descriptor must have the index's length (the
    /// first keyframe of an empty index fixes it when it is 0).
    pub fn upsert(&mut self, keyframe: SemanticKeyframe) -> bool {
        // A replaced keyframe keeps its verdicts: it is the same keyframe.
        let replaced = self.remove_row(&keyframe.key);
        if self.matrix.dim() == 0 && self.matrix.is_empty() {
            self.matrix = DescriptorMatrix::new(keyframe.features.descriptor.len());
        }
        assert!(
            self.rows.len() < NO_ROW as usize,
            "at most 2³² − 1 keyframes"
        );
        let row = self.matrix.push(&keyframe.features.descriptor);
        self.attach(row, keyframe);
        replaced
    }

    /// Adds everything but the descriptor of the keyframe in matrix row
    /// `row`, which must be the next row (`row == len()`), and links it
    /// into its track.
    fn attach(&mut self, row: usize, keyframe: SemanticKeyframe) {
        debug_assert_eq!(row, self.rows.len());
        self.changes += 1;
        self.preds.push(NO_ROW);
        self.tags
            .push(crate::vpr::calibration::sample_tag(&keyframe.key));
        self.appearance.push(&keyframe.features.appearance);
        for text in distinct_texts(&keyframe.features.objects) {
            *self.text_df.entry(text).or_insert(0) += 1;
        }
        let (robot, session) = self
            .interner
            .intern(&keyframe.key.robot_id, &keyframe.key.session_id);
        self.by_key.insert(keyframe.key.clone(), row);
        self.ids.push(RowIds {
            robot,
            session,
            map_id: keyframe.map_id,
            frame_id: keyframe.frame_id,
            keyframe_id: keyframe.key.keyframe_id,
        });
        self.rows.push(RowMeta {
            key: keyframe.key,
            frame_id: keyframe.frame_id,
            timestamp: keyframe.timestamp,
            map_id: keyframe.map_id,
            pose: keyframe.pose,
            scene: keyframe.features.scene,
            objects: keyframe.features.objects,
        });
        self.link(row);
    }

    /// Removes a keyframe and every verdict naming it; returns true if it
    /// was stored.
    pub fn remove(&mut self, key: &KeyframeKey) -> bool {
        if self.verdicts.forget(key) > 0 {
            self.forget_operating_point();
        }
        let removed = self.remove_row(key);
        if removed {
            *self.erasures.entry(key.session()).or_insert(0) += 1;
        }
        removed
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

    /// The stored verdicts.
    pub fn verdicts(&self) -> &VerdictBook {
        &self.verdicts
    }

    /// Records a verdict (the store has checked that both of its keyframes
    /// are stored); says whether it replaced one on the same pair and kind.
    pub fn record_verdict(&mut self, verdict: Verdict) -> bool {
        self.forget_operating_point();
        self.verdicts.record(verdict)
    }

    /// The store's operating point at `now` (seconds since the epoch):
    /// the threshold a query that names none gets, adapted from the
    /// scored verdicts by [`vpr::operating_point`] when
    /// `vpr.verdicts.enabled` and `adapt_threshold` are on, else the
    /// configured one. Reused for [`OPERATING_POINT_REFRESH_S`] while no
    /// verdict changes.
    pub fn operating_point(&self, params: &vpr::VprParams, now: f64) -> OperatingPoint {
        let base = params.threshold();
        let verdict_params = &params.verdicts;
        if !(verdict_params.enabled && verdict_params.adapt_threshold) {
            return OperatingPoint::fixed(base);
        }
        let mut cache = self
            .operating_point
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(c) = cache.as_ref() {
            if c.base == base
                && c.params == *verdict_params
                && (now - c.at).abs() < OPERATING_POINT_REFRESH_S
            {
                return c.point;
            }
        }
        let samples: Vec<Sample> = self
            .verdicts
            .iter()
            .filter(|v| v.kind != VerificationKind::Relocalisation)
            .filter_map(|v| {
                Some(Sample {
                    score: v.score?,
                    accepted: v.accepted,
                    weight: verdict_params.weight(v.reported_at, now),
                })
            })
            .collect();
        let point = vpr::operating_point::adapt(&verdict_params.rule(base), &samples);
        *cache = Some(CachedPoint {
            params: verdict_params.clone(),
            base,
            at: now,
            point,
        });
        point
    }

    /// Drops the cached operating point (the verdicts changed).
    fn forget_operating_point(&mut self) {
        *self
            .operating_point
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner) = None;
    }

    /// Where a stored keyframe is (its map and camera centre), for the
    /// verdicts' place tests.
    pub fn place<'a>(&'a self, key: &KeyframeKey) -> Option<Place<'a>> {
        Some(self.place_of_row(self.row_of(key)?))
    }

    /// The stored keyframes at `place`'s place: those of its map at most
    /// `radius` from it (itself among them when stored). One pass over
    /// that map's rows, a few flops each: far less than the query's scan
    /// of the same rows.
    pub fn keyframes_near<'a>(
        &'a self,
        place: &Place,
        params: &VerdictParams,
    ) -> Vec<&'a KeyframeKey> {
        let map = MapKey {
            session: place.key.session(),
            map_id: place.map_id,
        };
        let radius = params.radius(place.spacing);
        self.tracks
            .get(&map)
            .into_iter()
            .flat_map(|track| track.values())
            .map(|&row| self.place_with_spacing(row, place.spacing))
            .filter(|other| place.within(other, radius))
            .map(|other| other.key)
            .collect()
    }

    /// `s`, a map's keyframe spacing: the median distance between the
    /// stored positions of its consecutive keyframes (by keyframe id); 0
    /// for an unknown map or one of a single keyframe. The verdicts'
    /// same-place radius is measured in it ([`vpr::feedback`]), since a
    /// map's units need not be metres. Computed once per change of the
    /// map (one pass over its keyframes) and cached.
    pub fn map_spacing(&self, map: &MapKey) -> f64 {
        let mut cache = self.spacings.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(&spacing) = cache.get(map) {
            return spacing;
        }
        let Some(track) = self.tracks.get(map) else {
            return 0.0;
        };
        let positions: Vec<[f64; 3]> = track
            .values()
            .map(|&row| self.rows[row].pose.translation)
            .collect();
        let mut steps: Vec<f64> = positions
            .windows(2)
            .map(|w| squared_distance(w[0], w[1]).sqrt())
            .collect();
        let spacing = if steps.is_empty() {
            0.0
        } else {
            let middle = steps.len() / 2;
            *steps.select_nth_unstable_by(middle, f64::total_cmp).1
        };
        cache.insert(map.clone(), spacing);
        spacing
    }

    /// Drops a map's cached spacing (its track or a pose in it changed).
    fn forget_spacing(&mut self, map: &MapKey) {
        self.spacings
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(map);
    }

    /// Where the keyframe of `row` is. Panics if `row` is out of range.
    pub fn place_of_row(&self, row: usize) -> Place<'_> {
        self.place_with_spacing(row, self.map_spacing(&self.rows[row].map_key()))
    }

    /// The place of `row` in a map whose spacing is already known.
    fn place_with_spacing(&self, row: usize, spacing: f64) -> Place<'_> {
        let meta = &self.rows[row];
        Place {
            key: &meta.key,
            map_id: meta.map_id,
            position: meta.pose.translation,
            spacing,
        }
    }

    /// Removes a keyframe's row, leaving its verdicts.
    fn remove_row(&mut self, key: &KeyframeKey) -> bool {
        let Some(row) = self.by_key.remove(key) else {
            return false;
        };
        self.changes += 1;
        self.unlink(row);
        for text in distinct_texts(&self.rows[row].objects) {
            if let Some(count) = self.text_df.get_mut(&text) {
                *count -= 1;
                if *count == 0 {
                    self.text_df.remove(&text);
                }
            }
        }
        // Move the last row into the hole and repoint everything that
        // referred to the last row.
        let last = self.rows.len() - 1;
        self.matrix.swap_remove(row);
        self.appearance.swap_remove(row);
        self.rows.swap_remove(row);
        self.ids.swap_remove(row);
        self.preds.swap_remove(row);
        self.tags.swap_remove(row);
        // The tail's last row fills the hole (or, without a tail, the
        // grouped rows' last one): the grouped rows end where they did, or
        // at the new end.
        self.grouped = self.grouped.min(last);
        if row != last {
            self.note_displaced(row);
            let moved = &self.rows[row];
            self.by_key.insert(moved.key.clone(), row);
            let map = moved.map_key();
            let id = moved.key.keyframe_id;
            let track = self.tracks.get_mut(&map).expect("moved row has a track");
            track.insert(id, row);
            if let Some((_, &next)) = track.range(id + 1..).next() {
                self.set_prev(next, Some(row));
            }
        }
        true
    }

    /// Moves a keyframe to a corrected pose and, optionally, another map.
    /// Returns false if the keyframe is not stored.
    pub fn update_pose(&mut self, key: &KeyframeKey, pose: Pose, map_id: Option<u64>) -> bool {
        let Some(row) = self.row_of(key) else {
            return false;
        };
        self.forget_spacing(&self.rows[row].map_key());
        self.changes += 1;
        self.rows[row].pose = pose;
        if let Some(map_id) = map_id {
            if map_id != self.rows[row].map_id {
                self.unlink(row);
                self.rows[row].map_id = map_id;
                self.ids[row].map_id = map_id;
                self.link(row);
                self.note_displaced(row);
            }
        }
        true
    }

    /// Inserts `row` into its map's track and fixes the predecessor links of
    /// it and of its successor.
    fn link(&mut self, row: usize) {
        let map = self.rows[row].map_key();
        let id = self.rows[row].key.keyframe_id;
        self.forget_spacing(&map);
        let track = self.tracks.entry(map).or_default();
        track.insert(id, row);
        let prev = track.range(..id).next_back().map(|(_, &r)| r);
        let next = track.range(id + 1..).next().map(|(_, &r)| r);
        self.set_prev(row, prev);
        if let Some(next) = next {
            self.set_prev(next, Some(row));
        }
    }

    /// Takes `row` out of its map's track, joining its neighbours.
    fn unlink(&mut self, row: usize) {
        let map = self.rows[row].map_key();
        let id = self.rows[row].key.keyframe_id;
        self.forget_spacing(&map);
        let prev = self.prev(row);
        let Some(track) = self.tracks.get_mut(&map) else {
            return;
        };
        track.remove(&id);
        let next = track.range(id + 1..).next().map(|(_, &r)| r);
        if track.is_empty() {
            self.tracks.remove(&map);
        }
        if let Some(next) = next {
            self.set_prev(next, prev);
        }
        self.set_prev(row, None);
    }

    fn prev(&self, row: usize) -> Option<usize> {
        let p = self.preds[row];
        (p != NO_ROW).then_some(p as usize)
    }

    fn set_prev(&mut self, row: usize, prev: Option<usize>) {
        // Rows fit in u32: `upsert` stops short of NO_ROW.
        self.preds[row] = prev.map_or(NO_ROW, |p| p as u32);
    }
}

/// The largest share of the store a query's admitted maps may hold for
/// its scan to visit only their rows ([`Index::eligibility`]). Past it a
/// scan of every row in order costs no more than gathering the rows
/// (`humem bench scan`, the scoped case).
pub const PARTITION_MAX_SHARE: f64 = 0.5;

/// A query's eligibility rule bound to an index's rows, with the rows it
/// can admit when they are a small part of the store.
#[derive(Debug, Clone)]
pub struct RowEligibility<'a> {
    rule: Eligibility,
    ids: &'a [RowIds],
    partition: Option<Vec<usize>>,
}

impl RowEligibility<'_> {
    /// Whether `row` may be proposed. Panics if `row` is out of range.
    #[inline]
    pub fn test(&self, row: usize) -> bool {
        self.rule.test(&self.ids[row])
    }

    /// The same rule, naming no partition: a scan with it visits every
    /// row (the reference the partitioned scan is checked against, and the
    /// baseline `humem bench scan` measures it with).
    pub fn without_partition(mut self) -> Self {
        self.partition = None;
        self
    }
}

impl vpr::RowFilter for RowEligibility<'_> {
    #[inline]
    fn test(&self, row: usize) -> bool {
        RowEligibility::test(self, row)
    }

    fn partition(&self) -> Option<&[usize]> {
        self.partition.as_deref()
    }
}

/// The distinct normalised strings read on a keyframe's objects: each counts
/// once per keyframe in the document frequency.
fn distinct_texts(objects: &[ObjectObservation]) -> HashSet<String> {
    objects
        .iter()
        .flat_map(|o| o.texts.iter())
        .map(|t| vpr::text::normalize(&t.text))
        .filter(|t| !t.is_empty())
        .collect()
}

impl KeyframeMemory for Index {
    fn descriptors(&self) -> &DescriptorMatrix {
        &self.matrix
    }

    fn appearance(&self) -> &AppearanceMatrix {
        &self.appearance
    }

    fn scene(&self, row: usize) -> &[SceneClass] {
        &self.rows[row].scene
    }

    fn predecessor(&self, row: usize) -> Option<usize> {
        self.prev(row)
    }

    fn objects(&self, row: usize) -> &[ObjectObservation] {
        &self.rows[row].objects
    }

    fn text_document_frequency(&self, normalized: &str) -> u32 {
        self.text_df.get(normalized).copied().unwrap_or(0)
    }

    fn keyframe_count(&self) -> u32 {
        u32::try_from(self.rows.len()).unwrap_or(u32::MAX)
    }

    fn sample_tag(&self, row: usize) -> u32 {
        self.tags[row]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe::{Features, TextObservation};

    fn kf(session: &str, id: u64, map: u64, text: &str) -> SemanticKeyframe {
        let mut keyframe = kf_of("r", session, id, map);
        keyframe.features.objects[0].texts[0].text = text.into();
        keyframe
    }

    /// Keyframe `id` of a robot's session in map `map`; its descriptor is
    /// `[id, 1]`.
    pub(super) fn kf_of(robot: &str, session: &str, id: u64, map: u64) -> SemanticKeyframe {
        SemanticKeyframe {
            key: KeyframeKey {
                robot_id: robot.into(),
                session_id: session.into(),
                keyframe_id: id,
            },
            frame_id: id * 10,
            timestamp: id as f64,
            map_id: map,
            pose: Pose::default(),
            features: Features {
                descriptor: vec![id as f32, 1.0],
                appearance: vec![],
                scene: vec![],
                objects: vec![ObjectObservation {
                    class_name: "sign".into(),
                    confidence: 1.0,
                    centroid: [0.5, 0.5],
                    area: 0.1,
                    texts: vec![TextObservation {
                        text: format!("t{id}"),
                        confidence: 1.0,
                    }],
                }],
            },
        }
    }

    fn prev_id(index: &Index, session: &str, id: u64) -> Option<u64> {
        let key = KeyframeKey {
            robot_id: "r".into(),
            session_id: session.into(),
            keyframe_id: id,
        };
        let row = index.row_of(&key)?;
        index
            .predecessor(row)
            .map(|r| index.meta(r).key.keyframe_id)
    }

    /// Checks every invariant against a from-scratch recomputation.
    pub(super) fn check(index: &Index) {
        assert_eq!(index.matrix.len(), index.rows.len());
        assert_eq!(index.by_key.len(), index.rows.len());
        assert_eq!(index.ids.len(), index.rows.len());
        assert_eq!(index.tags.len(), index.rows.len());
        assert_eq!(index.appearance.len(), index.rows.len());
        for (row, meta) in index.rows.iter().enumerate() {
            assert_eq!(index.by_key[&meta.key], row);
            assert_eq!(index.tracks[&meta.map_key()][&meta.key.keyframe_id], row);
            assert_eq!(
                index.tags[row],
                crate::vpr::calibration::sample_tag(&meta.key)
            );
            assert_eq!(index.matrix.row(row)[0], meta.key.keyframe_id as f32);
            let ids = index.ids[row];
            assert_eq!(
                (ids.keyframe_id, ids.frame_id, ids.map_id),
                (meta.key.keyframe_id, meta.frame_id, meta.map_id)
            );
            let expected_prev = index
                .rows
                .iter()
                .enumerate()
                .filter(|(_, m)| {
                    m.map_key() == meta.map_key() && m.key.keyframe_id < meta.key.keyframe_id
                })
                .max_by_key(|(_, m)| m.key.keyframe_id)
                .map(|(r, _)| r);
            assert_eq!(index.prev(row), expected_prev, "prev of {:?}", meta.key);
        }
        let tracked: usize = index.tracks.values().map(|t| t.len()).sum();
        assert_eq!(tracked, index.rows.len());
    }

    #[test]
    fn erasures_are_counted_per_session_and_replacements_are_not() {
        let mut index = Index::new(0);
        let session = |name: &str| kf_of("r", name, 0, 0).key.session();
        index.upsert(kf("s", 1, 0, "a"));
        index.upsert(kf("s", 2, 0, "b"));
        index.upsert(kf("t", 1, 0, "c"));
        // A replaced keyframe is the same keyframe: no erasure.
        index.upsert(kf("s", 1, 0, "a2"));
        assert_eq!(index.session_erasures(&session("s")), 0);
        assert!(index.remove(&kf("s", 1, 0, "").key));
        assert!(!index.remove(&kf("s", 1, 0, "").key), "already gone");
        assert!(index.remove(&kf("s", 2, 0, "").key));
        assert_eq!(index.session_erasures(&session("s")), 2);
        assert_eq!(index.session_erasures(&session("t")), 0);
        // The count outlives the session's keyframes, so it never repeats.
        index.upsert(kf("s", 3, 0, "d"));
        assert_eq!(index.session_erasures(&session("s")), 2);
    }

    #[test]
    fn predecessors_follow_keyframe_order_within_a_map() {
        let mut index = Index::new(0);
        for id in [3, 1, 2, 5] {
            index.upsert(kf("s", id, 0, "x"));
        }
        index.upsert(kf("s", 4, 1, "x"));
        check(&index);
        assert_eq!(prev_id(&index, "s", 1), None);
        assert_eq!(prev_id(&index, "s", 2), Some(1));
        assert_eq!(prev_id(&index, "s", 3), Some(2));
        assert_eq!(prev_id(&index, "s", 5), Some(3));
        assert_eq!(prev_id(&index, "s", 4), None, "other map");
    }

    #[test]
    fn removal_and_swaps_keep_links_right() {
        let mut index = Index::new(0);
        for id in 0..20 {
            index.upsert(kf(if id % 2 == 0 { "a" } else { "b" }, id, id % 3, "x"));
        }
        for id in [0, 7, 19, 10, 4] {
            let key = index
                .rows
                .iter()
                .find(|m| m.key.keyframe_id == id)
                .unwrap()
                .key
                .clone();
            assert!(index.remove(&key));
            assert!(!index.remove(&key));
            check(&index);
        }
        let key = index.rows[3].key.clone();
        assert!(index.update_pose(&key, Pose::default(), Some(9)));
        check(&index);
        assert_eq!(index.len(), 15);
    }

    /// The spacing is the median step between consecutive keyframes (by
    /// id, not insertion order) and follows inserts, pose updates, moves
    /// to another map and removals.
    #[test]
    fn map_spacing_is_the_median_step_and_follows_changes() {
        let at = |id: u64, x: f64| {
            let mut k = kf("s", id, 0, "x");
            k.pose.translation = [x, 0.0, 0.0];
            k
        };
        let map = MapKey {
            session: SessionKey {
                robot_id: "r".into(),
                session_id: "s".into(),
            },
            map_id: 0,
        };
        let key = |id: u64| KeyframeKey {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_id: id,
        };
        let mut index = Index::new(0);
        assert_eq!(index.map_spacing(&map), 0.0, "unknown map");
        index.upsert(at(1, 0.0));
        assert_eq!(index.map_spacing(&map), 0.0, "one keyframe");
        // Ids 1..4 at x = 0, 1, 3, 10 (inserted out of order): steps 1, 2, 7.
        for (id, x) in [(4, 10.0), (2, 1.0), (3, 3.0)] {
            index.upsert(at(id, x));
        }
        assert_eq!(index.map_spacing(&map), 2.0);
        assert_eq!(index.place(&key(2)).unwrap().spacing, 2.0);
        // A corrected pose: id 4 at x = 3.5 (steps 1, 2, 0.5).
        let pose = Pose {
            translation: [3.5, 0.0, 0.0],
            ..Pose::default()
        };
        index.update_pose(&key(4), pose, None);
        assert_eq!(index.map_spacing(&map), 1.0);
        // Id 3 moves to map 1: steps 1, 2.5; the median is the upper one.
        index.update_pose(
            &key(3),
            index.meta(index.row_of(&key(3)).unwrap()).pose,
            Some(1),
        );
        assert_eq!(index.map_spacing(&map), 2.5);
        index.remove(&key(4));
        assert_eq!(index.map_spacing(&map), 1.0);
    }

    #[test]
    fn replacing_a_keyframe_keeps_one_row() {
        let mut index = Index::new(0);
        assert!(!index.upsert(kf("s", 1, 0, "x")));
        assert!(index.upsert(kf("s", 1, 0, "y")));
        assert_eq!(index.len(), 1);
        check(&index);
    }

    #[test]
    fn document_frequency_counts_keyframes() {
        let mut index = Index::new(0);
        index.upsert(kf("s", 1, 0, "Exit 12"));
        index.upsert(kf("s", 2, 0, "EXIT-12"));
        index.upsert(kf("s", 3, 0, "Room 5"));
        let exit = vpr::text::normalize("exit 12");
        assert_eq!(index.text_document_frequency(&exit), 2);
        let key = index.rows[0].key.clone();
        index.remove(&key);
        assert_eq!(index.text_document_frequency(&exit), 1);
        assert_eq!(index.keyframe_count(), 2);
    }
}
