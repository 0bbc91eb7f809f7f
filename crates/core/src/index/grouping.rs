//! Keeping each map's rows together in the matrix, so that a query whose
//! scope admits a few maps reads a few long runs of rows instead of one
//! row in every few dozen.
//!
//! A fleet's keyframes arrive interleaved (robot 0, robot 1, …, robot 0,
//! …), and rows are appended in arrival order, so one map's rows are
//! scattered over the whole matrix: a partitioned scan then pays a fresh
//! memory read for every row (about 1.2 µs a row against 0.06 µs in a long
//! run, `humem bench scan`, the scoped case). Sorting the whole matrix
//! again and again would cost a copy of the store per change; instead the
//! rows appended since the last grouping (the *tail*) are sorted among
//! themselves by (robot, session, map, keyframe id) once there are
//! [`GROUP_TAIL_ROWS`] of them: the order and copies of the rows in it are
//! made while queries go on ([`Index::plan_grouping`]), and only
//! putting them in place needs the index to itself
//! ([`Index::apply_grouping`]). Each grouped tail then holds one run per
//! map, so a map's rows form one run per tail it wrote to (a robot that
//! inserts one keyframe in fifty gets runs of about eighty rows), which a
//! scan reads at the speed of a long run; only the rows of the current,
//! not yet grouped tail stay scattered. Moving a tail costs a copy of
//! [`GROUP_TAIL_ROWS`] rows, whatever the store's size.
//!
//! Rows are positions, not identities: the answers of a query depend on
//! the rows' contents only (ties between equal scores, which order by row,
//! aside; replicas and restarts already hold rows in other orders), and a
//! grouping keeps every keyframe, link and count as it was.
//!
//! Erasures move the last row into the hole (see [`Index::remove`]) and
//! corrected poses may move a keyframe to another map in place: the rows
//! so displaced sit alone among another map's rows (ORB-SLAM3 culls
//! keyframes all the time, and a replaced keyframe is an erasure plus an
//! append). Once they are an eighth of the grouped rows
//! ([`REGROUP_ALL_SHARE`]), the next grouping sorts every row instead of
//! the tail: a copy of the whole matrix, made under the shared lock and
//! swapped in (not copied) under the exclusive one, so it holds the index
//! only to move the row tables; the copy needs the matrix's size again in
//! memory for that moment. Rows kept in a file are never regrouped whole
//! (that would read the file into memory); their tails still are.

use super::{Index, RowMeta, NO_ROW};
use crate::row_ids::RowIds;
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::matrix::MatrixRows;

/// Rows appended since the last grouping from which
/// [`Index::group_tail_if_due`] groups them.
pub const GROUP_TAIL_ROWS: usize = 4096;

/// The share of the grouped rows that erasures and map moves may displace
/// before a grouping sorts every row (and at least [`GROUP_TAIL_ROWS`]).
pub const REGROUP_ALL_SHARE: f64 = 0.125;

impl Index {
    /// Rows appended since the tail was last grouped.
    pub fn ungrouped_rows(&self) -> usize {
        self.rows.len() - self.grouped.min(self.rows.len())
    }

    /// Rows of the grouped part that an erasure or a map move left among
    /// another map's rows since every row was last sorted.
    pub fn displaced_rows(&self) -> usize {
        self.displaced
    }

    /// Whether a grouping is due: the tail holds [`GROUP_TAIL_ROWS`] rows,
    /// or the displaced rows call for sorting every row.
    pub fn grouping_due(&self) -> bool {
        self.ungrouped_rows() >= GROUP_TAIL_ROWS || self.regroup_all_due()
    }

    /// Whether the next grouping sorts every row: the displaced rows are
    /// [`REGROUP_ALL_SHARE`] of the grouped ones (at least
    /// [`GROUP_TAIL_ROWS`]) and the descriptors are in memory.
    fn regroup_all_due(&self) -> bool {
        let grouped = self.grouped.min(self.rows.len());
        self.matrix.in_memory()
            && self.displaced >= GROUP_TAIL_ROWS
            && self.displaced as f64 >= REGROUP_ALL_SHARE * grouped as f64
    }

    /// Groups ([`Index::group_tail`]) when [`Index::grouping_due`]; returns
    /// the rows it reordered (0: not due). The store's writer does the same
    /// in two halves, the copies under the shared lock and only their
    /// placing under the exclusive one.
    pub fn group_tail_if_due(&mut self) -> usize {
        if self.grouping_due() {
            self.group_tail()
        } else {
            0
        }
    }

    /// Takes every row as grouped, as a store opened from its snapshot
    /// (written in the grouped order) or from its tree (in key order,
    /// robot by robot and session by session) holds them.
    pub fn mark_grouped(&mut self) {
        self.grouped = self.rows.len();
    }

    /// How many times the rows have been reordered since this index was
    /// made: a reader that reads the rows in pieces, releasing the lock in
    /// between (the snapshot writer), checks that it did not change.
    pub fn layout_epoch(&self) -> u64 {
        self.layout_epoch
    }

    /// Sorts the rows appended since the last grouping (every row, when the
    /// displaced ones call for it) by (robot, session, map, keyframe id),
    /// everything row-aligned moving with them, and returns how many there
    /// were. Rows before them stay where they are. [`Index::plan_grouping`] then
    /// [`Index::apply_grouping`], for an index no one else reads.
    pub fn group_tail(&mut self) -> usize {
        match self.plan_grouping() {
            Some(plan) => self.apply_grouping(plan).0,
            None => 0,
        }
    }

    /// The first half of [`Index::group_tail`], which only reads: the
    /// tail's new order and copies of its descriptors, codes and
    /// thumbnails in that order, the bulk of the work, so that queries go
    /// on meanwhile under a shared lock. `None` without a tail.
    pub fn plan_grouping(&self) -> Option<Grouping> {
        let from = if self.regroup_all_due() {
            0
        } else {
            self.grouped.min(self.rows.len())
        };
        self.plan_grouping_from(from)
    }

    /// Sorts every row, wherever [`Index::grouping_due`] stands (for tests).
    #[cfg(test)]
    pub(crate) fn group_all(&mut self) -> usize {
        match self.plan_grouping_from(0) {
            Some(plan) => self.apply_grouping(plan).0,
            None => 0,
        }
    }

    /// A grouping of the rows from `from` on: everything that is copied,
    /// cloned or recomputed is done here, under a shared lock.
    fn plan_grouping_from(&self, from: usize) -> Option<Grouping> {
        let len = self.rows.len();
        if from == len {
            return None;
        }
        let mut order: Vec<usize> = (from..len).collect();
        order.sort_unstable_by_key(|&row| {
            let ids = &self.ids[row];
            (ids.robot, ids.session, ids.map_id, ids.keyframe_id)
        });
        // new_row[old − from]: where each moved row goes.
        let mut new_row = vec![0usize; order.len()];
        for (i, &old) in order.iter().enumerate() {
            new_row[old - from] = from + i;
        }
        // A predecessor anywhere may be a moved row: every link is redone.
        let relink = |pred: u32| {
            let p = pred as usize;
            if pred == NO_ROW || p < from {
                pred
            } else {
                new_row[p - from] as u32
            }
        };
        let preds = self.preds[..from]
            .iter()
            .chain(order.iter().map(|&old| &self.preds[old]))
            .map(|&pred| relink(pred))
            .collect();
        Some(Grouping {
            from,
            changes: self.changes,
            matrix: self.matrix.gathered(&order),
            appearance: self.appearance.gathered(&order),
            rows: order.iter().map(|&old| self.rows[old].clone()).collect(),
            ids: order.iter().map(|&old| self.ids[old]).collect(),
            tags: order.iter().map(|&old| self.tags[old]).collect(),
            preds,
            new_row,
        })
    }

    /// The second half of [`Index::group_tail`]: puts the planned rows and
    /// tables in place (copies of the tail's descriptors, codes and
    /// thumbnails; every row's buffers swapped in, not copied, when all
    /// rows move) and repoints the key and track tables. Returns the rows
    /// moved, or 0, doing nothing, if the index changed since the plan was
    /// made, and what was replaced: drop it after letting go of the lock
    /// (freeing a whole matrix takes a while).
    pub fn apply_grouping(&mut self, plan: Grouping) -> (usize, Replaced) {
        let Grouping {
            from,
            changes,
            matrix,
            appearance,
            rows,
            ids,
            tags,
            preds,
            new_row,
        } = plan;
        let len = self.rows.len();
        if changes != self.changes || from + new_row.len() != len {
            return (0, Replaced::default());
        }
        let replaced = Replaced {
            _matrix: self.matrix.overwrite_tail(from, matrix),
            _appearance: self.appearance.overwrite_tail(from, appearance),
            _rows: replace_tail(&mut self.rows, from, rows),
            _ids: replace_tail(&mut self.ids, from, ids),
            _tags: replace_tail(&mut self.tags, from, tags),
            _preds: std::mem::replace(&mut self.preds, preds),
        };
        if from == 0 {
            // Every row moved: one pass over each table, no lookups.
            for row in self.by_key.values_mut() {
                *row = new_row[*row];
            }
            for row in self
                .tracks
                .values_mut()
                .flat_map(|track| track.values_mut())
            {
                *row = new_row[*row];
            }
        } else {
            for row in from..len {
                let meta = &self.rows[row];
                *self
                    .by_key
                    .get_mut(&meta.key)
                    .expect("every row has its key") = row;
                *self
                    .tracks
                    .get_mut(&meta.map_key())
                    .and_then(|track| track.get_mut(&meta.key.keyframe_id))
                    .expect("every row is in its track") = row;
            }
        }
        self.grouped = len;
        if from == 0 {
            self.displaced = 0;
        }
        self.layout_epoch += 1;
        self.changes += 1;
        (len - from, replaced)
    }
}

/// A grouping of an index's rows from some row on, planned and not yet
/// applied (see [`Index::plan_grouping`]).
#[derive(Debug)]
pub struct Grouping {
    from: usize,
    /// The index's change count when planned.
    changes: u64,
    matrix: MatrixRows,
    appearance: AppearanceMatrix,
    /// The moved rows' tables, in their new order.
    rows: Vec<RowMeta>,
    ids: Vec<RowIds>,
    tags: Vec<u32>,
    /// Every row's predecessor, after the move.
    preds: Vec<u32>,
    /// The new row of each moved row, by old row − `from`.
    new_row: Vec<usize>,
}

/// What an applied grouping took out of the index
/// ([`Index::apply_grouping`]), held only to be dropped later.
#[derive(Debug, Default)]
#[must_use = "drop it once the index's lock is let go"]
pub struct Replaced {
    _matrix: Option<MatrixRows>,
    _appearance: Option<AppearanceMatrix>,
    _rows: Vec<RowMeta>,
    _ids: Vec<RowIds>,
    _tags: Vec<u32>,
    _preds: Vec<u32>,
}

/// Puts `new` in place of `values[from..]` and returns what was there
/// (the whole buffer swapped when `from` is 0).
fn replace_tail<T>(values: &mut Vec<T>, from: usize, new: Vec<T>) -> Vec<T> {
    if from == 0 {
        return std::mem::replace(values, new);
    }
    let old = values.split_off(from);
    values.extend(new);
    old
}

#[cfg(test)]
mod tests {
    use super::super::tests::{check, kf_of};
    use super::*;
    use crate::keyframe::SemanticKeyframe;
    use proptest::prelude::*;

    /// Every stored keyframe, by key, as the index gives it back.
    fn contents(index: &Index) -> Vec<(String, SemanticKeyframe)> {
        let mut all: Vec<_> = (0..index.len())
            .map(|row| {
                let kf = index.keyframe(row);
                (format!("{:?}", kf.key), kf)
            })
            .collect();
        all.sort_by(|a, b| a.0.cmp(&b.0));
        all
    }

    /// The runs of consecutive rows each map's rows form.
    fn runs_per_map(index: &Index) -> std::collections::HashMap<super::super::MapKey, usize> {
        let mut runs = std::collections::HashMap::new();
        for row in 0..index.len() {
            let map = index.meta(row).map_key();
            if row == 0 || index.meta(row - 1).map_key() != map {
                *runs.entry(map).or_insert(0) += 1;
            }
        }
        runs
    }

    #[test]
    fn a_grouped_tail_holds_one_run_per_map_and_the_same_keyframes() {
        let mut index = Index::new(0);
        // Three robots' keyframes interleaved, two maps each.
        for step in 0..40u64 {
            for robot in ["a", "b", "c"] {
                index.upsert(kf_of(robot, "s", step, step / 20));
            }
        }
        let before = contents(&index);
        assert_eq!(index.ungrouped_rows(), 120);
        assert_eq!(runs_per_map(&index).values().max(), Some(&20));

        assert_eq!(index.group_tail(), 120);
        check(&index);
        assert_eq!(contents(&index), before);
        assert!(runs_per_map(&index).values().all(|&runs| runs == 1));
        assert_eq!(index.ungrouped_rows(), 0);
        assert_eq!(index.layout_epoch(), 1);
        // The codes moved with their rows: they are those of the rows.
        let rebuilt = crate::vpr::codes::CodeMatrix::from_rows(
            index.dim(),
            &index.matrix.rows(0, index.len()),
        );
        assert_eq!(index.matrix.codes(), &rebuilt);

        // A second tail: rows before it stay, the new ones group among
        // themselves.
        let first_rows: Vec<_> = (0..index.len())
            .map(|r| index.meta(r).key.clone())
            .collect();
        for step in 40..50u64 {
            for robot in ["c", "a"] {
                index.upsert(kf_of(robot, "s", step, 1));
            }
        }
        assert_eq!(index.group_tail(), 20);
        check(&index);
        let kept: Vec<_> = (0..first_rows.len())
            .map(|r| index.meta(r).key.clone())
            .collect();
        assert_eq!(kept, first_rows);
        assert!(runs_per_map(&index).values().all(|&runs| runs <= 2));
    }

    #[test]
    fn erasures_that_displace_an_eighth_of_the_rows_make_the_next_grouping_sort_every_row() {
        let mut index = Index::new(0);
        let per_robot = (8 * GROUP_TAIL_ROWS / 2) as u64;
        for id in 0..per_robot {
            for robot in ["a", "b"] {
                index.upsert(kf_of(robot, "s", id, 0));
            }
        }
        index.mark_grouped();
        // ORB-SLAM3 culls keyframes: every fourth of robot a's.
        let culled = (0..per_robot).step_by(4);
        for id in culled.clone() {
            index.remove(&kf_of("a", "s", id, 0).key);
        }
        let displaced = index.displaced_rows();
        assert!(displaced >= GROUP_TAIL_ROWS && displaced <= culled.count());
        assert!(runs_per_map(&index).values().all(|&runs| runs > 100));
        assert_eq!(index.ungrouped_rows(), 0);
        assert!(index.grouping_due());
        let before = contents(&index);
        assert_eq!(index.group_tail_if_due(), index.len());
        assert_eq!(index.displaced_rows(), 0);
        assert!(!index.grouping_due());
        assert!(runs_per_map(&index).values().all(|&runs| runs == 1));
        assert_eq!(contents(&index), before);
        // A few erasures later nothing is due: the share is not reached.
        for id in (1..400).step_by(4) {
            index.remove(&kf_of("b", "s", id, 0).key);
        }
        assert!(!index.grouping_due());
    }

    #[test]
    fn a_plan_made_before_a_change_is_not_applied() {
        let mut index = Index::new(0);
        for step in 0..10u64 {
            for robot in ["a", "b"] {
                index.upsert(kf_of(robot, "s", step, 0));
            }
        }
        let plan = index.plan_grouping().unwrap();
        index.upsert(kf_of("c", "s", 0, 0));
        let before = contents(&index);
        assert_eq!(index.apply_grouping(plan).0, 0);
        check(&index);
        assert_eq!(contents(&index), before);
        assert_eq!((index.ungrouped_rows(), index.layout_epoch()), (21, 0));
        let plan = index.plan_grouping().unwrap();
        assert_eq!(index.apply_grouping(plan).0, 21);
        check(&index);
    }

    #[test]
    fn rows_kept_in_a_file_are_grouped_in_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut index = Index::new(0);
        for step in 0..30u64 {
            for robot in ["a", "b"] {
                index.upsert(kf_of(robot, "s", step, step % 3));
            }
        }
        index.move_descriptors_to_file(dir.path()).unwrap();
        index.mark_grouped();
        for step in 30..60u64 {
            for robot in ["b", "a"] {
                index.upsert(kf_of(robot, "s", step, step % 3));
            }
        }
        let before = contents(&index);
        assert_eq!(index.group_tail(), 60);
        assert!(!index.descriptors_in_memory());
        check(&index);
        assert_eq!(contents(&index), before);
    }

    #[test]
    fn grouping_is_due_from_the_threshold_on() {
        let mut index = Index::new(0);
        for id in 0..GROUP_TAIL_ROWS as u64 - 1 {
            index.upsert(kf_of(if id % 2 == 0 { "a" } else { "b" }, "s", id, 0));
        }
        assert_eq!(index.group_tail_if_due(), 0);
        index.upsert(kf_of("a", "s", 1 << 20, 0));
        assert_eq!(index.group_tail_if_due(), GROUP_TAIL_ROWS);
        assert_eq!(index.group_tail_if_due(), 0);
        index.mark_grouped();
        assert_eq!(index.ungrouped_rows(), 0);
    }

    /// What a test sequence does to the index.
    #[derive(Debug, Clone)]
    enum Step {
        Insert { robot: u8, id: u8, map: u8 },
        Remove { robot: u8, id: u8 },
        Move { robot: u8, id: u8, map: u8 },
        Group,
        GroupAll,
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            4 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Insert { robot, id, map }),
            1 => (0..3u8, 0..30u8).prop_map(|(robot, id)| Step::Remove { robot, id }),
            1 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Move { robot, id, map }),
            1 => Just(Step::Group),
            1 => Just(Step::GroupAll),
        ]
    }

    proptest! {
        /// Any sequence of inserts, erasures, map moves and groupings
        /// leaves the same keyframes, links and tracks as the same
        /// sequence without the groupings.
        #[test]
        fn grouping_changes_rows_only(steps in proptest::collection::vec(step(), 1..120)) {
            let (mut grouped, mut plain) = (Index::new(0), Index::new(0));
            for step in steps {
                let key = |robot: u8, id: u8| kf_of(&format!("r{robot}"), "s", u64::from(id), 0).key;
                match step {
                    Step::Insert { robot, id, map } => {
                        let kf = kf_of(&format!("r{robot}"), "s", u64::from(id), u64::from(map));
                        grouped.upsert(kf.clone());
                        plain.upsert(kf);
                    }
                    Step::Remove { robot, id } => {
                        grouped.remove(&key(robot, id));
                        plain.remove(&key(robot, id));
                    }
                    Step::Move { robot, id, map } => {
                        let pose = crate::keyframe::Pose::default();
                        grouped.update_pose(&key(robot, id), pose, Some(u64::from(map)));
                        plain.update_pose(&key(robot, id), pose, Some(u64::from(map)));
                    }
                    Step::Group => {
                        grouped.group_tail();
                    }
                    Step::GroupAll => {
                        grouped.group_all();
                        prop_assert_eq!(grouped.displaced_rows(), 0);
                        prop_assert!(runs_per_map(&grouped).values().all(|&runs| runs == 1));
                    }
                }
                check(&grouped);
                prop_assert_eq!(contents(&grouped), contents(&plain));
                for row in 0..grouped.len() {
                    let key = &grouped.meta(row).key;
                    let pred = |index: &Index, row: usize| {
                        index.prev(row).map(|p| index.meta(p).key.clone())
                    };
                    prop_assert_eq!(
                        pred(&grouped, row),
                        pred(&plain, plain.row_of(key).unwrap())
                    );
                }
                prop_assert_eq!(grouped.map_counts(), plain.map_counts());
            }
        }
    }
}
