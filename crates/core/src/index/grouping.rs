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
//! made while queries go on ([`Index::plan_tail_grouping`]), and only
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
//! corrected poses may move a keyframe to another map in place, so a store
//! that lives for months scatters its grouped rows again: after 30 % of a
//! 500 000-row fleet store was erased and replaced, the map a loop query
//! reads went from 66 runs to 3 499, and the query from 1.1 to 4 ms. So
//! the grouped rows are also watched in fixed windows of
//! [`GROUP_WINDOW_ROWS`]: each window counts the rows put into it out of
//! place since it was last sorted, and once one has
//! [`REGROUP_DISPLACED_ROWS`] of them it is sorted among itself the same
//! way, in the same two halves ([`Index::plan_window_regrouping`]), at
//! most one window per group of writes. A map's rows then form about one
//! run per window plus the rows displaced since (183 runs and 2.1 ms in
//! the same case), and each sorting costs a copy of one window however
//! large the store and however long it has lived. Sorting the whole store
//! would reach one run (1.8 ms) but hold every write for a copy of the
//! store.

use std::collections::HashSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use super::table::{Index, NO_ROW};
use crate::engine::matrix::MatrixRows;
use crate::vpr::appearance::AppearanceMatrix;

/// Rows appended since the last grouping from which
/// [`Index::group_tail_if_due`] groups them.
pub const GROUP_TAIL_ROWS: usize = 4096;

/// Rows in one window of the grouped rows, the unit that is sorted again
/// once erasures have scattered it. Chosen with `humem bench scan` (the
/// scoped case after 30 % churn, 500 000 rows): windows of 4 096 rows
/// left the queried map in 430 runs and the query at 3.0 ms, 8 192 in 183
/// runs at 2.1 ms (the index held for 8 ms a sorting), 16 384 in 131 runs
/// at 2.0 ms (held for 17 ms); the whole store sorted, 1.8 ms.
pub const GROUP_WINDOW_ROWS: usize = 2 * GROUP_TAIL_ROWS;

/// Rows put out of place in a window from which it is sorted again: a
/// sixty-fourth of it. Under steady replacement a window holds half that
/// out of place on average (each a run of its own), and one window is
/// sorted again per that many changes: a copy of 64 rows per change.
pub const REGROUP_DISPLACED_ROWS: u32 = (GROUP_WINDOW_ROWS / 64) as u32;

impl Index {
    /// Rows appended since the tail was last grouped.
    pub fn ungrouped_rows(&self) -> usize {
        self.rows.len() - self.grouped.min(self.rows.len())
    }

    /// Groups the tail ([`Index::group_tail`]) once it holds
    /// [`GROUP_TAIL_ROWS`] rows; returns the rows it reordered (0: not
    /// due). The store's writer does the same in two halves, the copies
    /// under the shared lock and only their placing under the exclusive
    /// one.
    pub fn group_tail_if_due(&mut self) -> usize {
        if self.ungrouped_rows() >= GROUP_TAIL_ROWS {
            self.group_tail()
        } else {
            0
        }
    }

    /// Sorts again the window of grouped rows most scattered by erasures
    /// and map moves, if one has [`REGROUP_DISPLACED_ROWS`] rows out of
    /// place; returns the rows it reordered (0: none due).
    /// [`Index::plan_window_regrouping`] then [`Index::apply_grouping`],
    /// for an index no one else reads.
    pub fn regroup_window_if_due(&mut self) -> usize {
        match self.plan_window_regrouping() {
            Some(plan) => self.apply_grouping(plan),
            None => 0,
        }
    }

    /// Takes every row as grouped, as a store opened from its snapshot
    /// (written in the row order it had) or from its tree (in key order,
    /// robot by robot and session by session) holds them. Each window
    /// counts as out of place the runs its rows form beyond one per map,
    /// so that a store scattered before a restart is still sorted again.
    pub fn mark_grouped(&mut self) {
        self.grouped = self.rows.len();
        self.displaced = self
            .ids
            .chunks(GROUP_WINDOW_ROWS)
            .map(|window| {
                let map = |ids: &crate::row_ids::RowIds| (ids.session, ids.map_id);
                let runs = 1 + window
                    .windows(2)
                    .filter(|w| map(&w[0]) != map(&w[1]))
                    .count();
                let maps = window.iter().map(map).collect::<HashSet<_>>().len();
                (runs - maps) as u32
            })
            .collect();
    }

    /// How many times the rows have been reordered since this index was
    /// made: a reader that reads the rows in pieces, releasing the lock in
    /// between (the snapshot writer), checks that it did not change.
    pub fn layout_epoch(&self) -> u64 {
        self.layout_epoch
    }

    /// Asks the index's writer not to group rows while the returned hold
    /// lives: a pass that reads the rows in pieces, letting the lock go
    /// between them, would have to start over after a grouping
    /// ([`Index::renumberings`]). Grouping is housekeeping that can wait;
    /// removals cannot, and still renumber rows.
    pub fn hold_row_order(&self) -> RowOrderHold {
        self.row_order_holds.fetch_add(1, Ordering::AcqRel);
        RowOrderHold(self.row_order_holds.clone())
    }

    /// Whether a pass asked that rows not be grouped now
    /// ([`Index::hold_row_order`]).
    pub fn row_order_held(&self) -> bool {
        self.row_order_holds.load(Ordering::Acquire) > 0
    }

    /// Counts a row put at `row` out of its map's run (by an erasure
    /// that moved the last row there, or a move to another map), if it
    /// is among the grouped rows.
    pub(super) fn note_displaced(&mut self, row: usize) {
        if row >= self.grouped {
            return;
        }
        let window = row / GROUP_WINDOW_ROWS;
        if self.displaced.len() <= window {
            self.displaced.resize(window + 1, 0);
        }
        self.displaced[window] = self.displaced[window].saturating_add(1);
    }

    /// The window of grouped rows with the most rows out of place, if it
    /// has [`REGROUP_DISPLACED_ROWS`] of them.
    pub fn window_due(&self) -> Option<usize> {
        let windows = self.grouped.div_ceil(GROUP_WINDOW_ROWS);
        self.displaced
            .iter()
            .take(windows)
            .enumerate()
            .filter(|&(_, &count)| count >= REGROUP_DISPLACED_ROWS)
            .max_by_key(|&(window, &count)| (count, std::cmp::Reverse(window)))
            .map(|(window, _)| window)
    }

    /// Sorts the rows appended since the last grouping by (robot,
    /// session, map, keyframe id), everything row-aligned moving with
    /// them, and returns how many there were. Rows before them stay where
    /// they are. [`Index::plan_tail_grouping`] then
    /// [`Index::apply_grouping`], for an index no one else reads.
    pub fn group_tail(&mut self) -> usize {
        match self.plan_tail_grouping() {
            Some(plan) => self.apply_grouping(plan),
            None => 0,
        }
    }

    /// The first half of [`Index::group_tail`], which only reads: the
    /// tail's new order and copies of its descriptors, codes and
    /// thumbnails in that order, the bulk of the work, so that queries go
    /// on meanwhile under a shared lock. `None` without a tail.
    pub fn plan_tail_grouping(&self) -> Option<RowGrouping> {
        let from = self.grouped.min(self.rows.len());
        (from < self.rows.len()).then(|| self.plan_grouping(from, self.rows.len(), None))
    }

    /// The first half of [`Index::regroup_window_if_due`], which only
    /// reads (as [`Index::plan_tail_grouping`]): the window most
    /// scattered since it was last sorted, if one is due.
    pub fn plan_window_regrouping(&self) -> Option<RowGrouping> {
        let window = self.window_due()?;
        let from = window * GROUP_WINDOW_ROWS;
        let to = (from + GROUP_WINDOW_ROWS).min(self.grouped);
        Some(self.plan_grouping(from, to, Some(window)))
    }

    /// Sorts rows `from..to` among themselves at once, as a window is
    /// sorted again: for tests, and for `humem bench scan` to show what
    /// sorting the whole store would reach (the writer never holds the
    /// index for that long).
    pub fn sort_rows(&mut self, from: usize, to: usize) -> usize {
        let plan = self.plan_grouping(from, to, Some(from / GROUP_WINDOW_ROWS));
        self.apply_grouping(plan)
    }

    /// Rows `from..to` in (robot, session, map, keyframe id) order, with
    /// copies of their descriptors, codes and thumbnails in that order.
    fn plan_grouping(&self, from: usize, to: usize, window: Option<usize>) -> RowGrouping {
        let mut order: Vec<usize> = (from..to).collect();
        order.sort_unstable_by_key(|&row| {
            let ids = &self.ids[row];
            (ids.robot, ids.session, ids.map_id, ids.keyframe_id)
        });
        RowGrouping {
            from,
            window,
            changes: self.changes,
            matrix: self.matrix.gathered(&order),
            appearance: self.appearance.gathered(&order),
            order,
        }
    }

    /// The second half of a grouping: puts the planned rows in place (one
    /// copy each of the descriptors, codes and thumbnails), moves the row
    /// tables and fixes every link to a moved row. Returns the rows moved,
    /// or 0, doing nothing, if the index changed since the plan was made.
    pub fn apply_grouping(&mut self, plan: RowGrouping) -> usize {
        let RowGrouping {
            from,
            window,
            changes,
            order,
            matrix,
            appearance,
        } = plan;
        let to = from + order.len();
        if changes != self.changes || to > self.rows.len() {
            return 0;
        }
        // new_row[old − from]: where each planned row goes.
        let mut new_row = vec![0usize; order.len()];
        for (i, &old) in order.iter().enumerate() {
            new_row[old - from] = from + i;
        }
        self.matrix.overwrite_rows(from, matrix);
        self.appearance.overwrite_rows(from, appearance);
        permute_range(&mut self.rows, from, &order);
        permute_range(&mut self.ids, from, &order);
        permute_range(&mut self.preds, from, &order);
        permute_range(&mut self.tags, from, &order);
        // A predecessor anywhere may be a moved row: every link is checked.
        for pred in &mut self.preds {
            let p = *pred as usize;
            if *pred != NO_ROW && (from..to).contains(&p) {
                *pred = new_row[p - from] as u32;
            }
        }
        for (i, &old) in order.iter().enumerate() {
            self.graph_moved(old, from + i);
        }
        for row in from..to {
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
        match window {
            Some(window) => {
                if let Some(count) = self.displaced.get_mut(window) {
                    *count = 0;
                }
            }
            None => self.grouped = to,
        }
        self.layout_epoch += 1;
        self.renumberings += 1;
        self.changes += 1;
        order.len()
    }
}

/// A pass's request that the index's rows not be grouped, until dropped
/// ([`Index::hold_row_order`]).
#[derive(Debug)]
pub struct RowOrderHold(Arc<AtomicUsize>);

impl Drop for RowOrderHold {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A sorting of a range of an index's rows (its tail, or a window of its
/// grouped rows), planned and not yet applied (see
/// [`Index::plan_tail_grouping`], [`Index::plan_window_regrouping`]).
#[derive(Debug)]
pub struct RowGrouping {
    from: usize,
    /// The window sorted again, or `None` for the tail.
    window: Option<usize>,
    /// The index's change count when planned.
    changes: u64,
    /// The old row of each new position from `from` on.
    order: Vec<usize>,
    matrix: MatrixRows,
    appearance: AppearanceMatrix,
}

/// Reorders `values[from..from + order.len()]` so that position `from + i`
/// holds the old `values[order[i]]`, in place by swaps along the
/// permutation's cycles (the values after the range are not touched).
fn permute_range<T>(values: &mut [T], from: usize, order: &[usize]) {
    let range = &mut values[from..from + order.len()];
    let mut done = vec![false; order.len()];
    for start in 0..order.len() {
        let mut at = start;
        while !done[at] {
            done[at] = true;
            let source = order[at] - from;
            if source == start {
                break;
            }
            range.swap(at, source);
            at = source;
        }
    }
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
        let rebuilt = crate::engine::codes::CodeMatrix::from_rows(
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
    fn a_plan_made_before_a_change_is_not_applied() {
        let mut index = Index::new(0);
        for step in 0..10u64 {
            for robot in ["a", "b"] {
                index.upsert(kf_of(robot, "s", step, 0));
            }
        }
        let plan = index.plan_tail_grouping().unwrap();
        index.upsert(kf_of("c", "s", 0, 0));
        let before = contents(&index);
        assert_eq!(index.apply_grouping(plan), 0);
        check(&index);
        assert_eq!(contents(&index), before);
        assert_eq!((index.ungrouped_rows(), index.layout_epoch()), (21, 0));
        let plan = index.plan_tail_grouping().unwrap();
        assert_eq!(index.apply_grouping(plan), 21);
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

    /// Every row's predecessor, by key.
    fn links(index: &Index) -> Vec<(String, Option<String>)> {
        let mut all: Vec<_> = (0..index.len())
            .map(|row| {
                let key = |row: usize| format!("{:?}", index.meta(row).key);
                (key(row), index.prev(row).map(key))
            })
            .collect();
        all.sort();
        all
    }

    /// Three robots' keyframes interleaved, `per_robot` each in two maps,
    /// every row grouped; then every other keyframe of robot "a"'s first
    /// `erased` × 2 erased, each hole filled with the store's last row.
    fn scattered(per_robot: u64, erased: u64) -> Index {
        let mut index = Index::new(0);
        for id in 0..per_robot {
            for robot in ["a", "b", "c"] {
                index.upsert(kf_of(robot, "s", id, id * 2 / per_robot));
            }
            index.group_tail_if_due();
        }
        index.group_tail();
        for id in 0..erased {
            assert!(index.remove(&kf_of("a", "s", 2 * id, 0).key));
        }
        index
    }

    #[test]
    fn a_window_scattered_by_erasures_is_sorted_again() {
        let per_robot = GROUP_WINDOW_ROWS as u64 + 1024;
        let due = u64::from(REGROUP_DISPLACED_ROWS);
        let mut index = scattered(per_robot, due - 1);
        assert_eq!(index.ungrouped_rows(), 0);
        // One displaced row short: nothing is due.
        assert!(index.plan_window_regrouping().is_none());
        assert!(index.remove(&kf_of("a", "s", 2 * (due - 1), 0).key));
        let runs_before = runs_per_map(&index);
        let a0 = super::super::MapKey {
            session: kf_of("a", "s", 0, 0).key.session(),
            map_id: 0,
        };
        // Every hole broke robot a's first map: a run per erasure.
        assert!(runs_before[&a0] > due as usize, "{}", runs_before[&a0]);
        let (before, links_before, epoch) = (contents(&index), links(&index), index.layout_epoch());

        assert_eq!(index.regroup_window_if_due(), GROUP_WINDOW_ROWS);
        assert_eq!(contents(&index), before);
        assert_eq!(links(&index), links_before);
        assert_eq!(index.layout_epoch(), epoch + 1);
        // Window 0 now holds one run of robot a's first map.
        let in_window_0 = |row: usize| row < GROUP_WINDOW_ROWS && index.meta(row).map_key() == a0;
        let runs = (0..GROUP_WINDOW_ROWS)
            .filter(|&row| in_window_0(row) && (row == 0 || !in_window_0(row - 1)))
            .count();
        assert_eq!(runs, 1);
        assert_eq!(index.regroup_window_if_due(), 0, "nothing else is due");
        // The codes moved with their rows.
        let rebuilt = crate::engine::codes::CodeMatrix::from_rows(
            index.dim(),
            &index.matrix.rows(0, index.len()),
        );
        assert_eq!(index.matrix.codes(), &rebuilt);
    }

    #[test]
    fn a_store_reopened_scattered_is_still_sorted_again() {
        let mut index = scattered(GROUP_WINDOW_ROWS as u64 / 3 * 2, 600);
        // As a store opened from a snapshot written in this order: the
        // counts are gone, and the runs tell the scatter.
        index.displaced.clear();
        assert!(index.plan_window_regrouping().is_none());
        index.mark_grouped();
        assert!(
            index.displaced[0] >= REGROUP_DISPLACED_ROWS,
            "{:?}",
            index.displaced
        );
        let before = contents(&index);
        assert_eq!(index.regroup_window_if_due(), GROUP_WINDOW_ROWS);
        assert_eq!(contents(&index), before);
        index.mark_grouped();
        // Sorted: one run per map in window 0.
        assert_eq!(index.displaced[0], 0);
        assert!(index.plan_window_regrouping().is_none());
    }

    /// What a test sequence does to the index.
    #[derive(Debug, Clone)]
    enum Step {
        Insert { robot: u8, id: u8, map: u8 },
        Remove { robot: u8, id: u8 },
        Move { robot: u8, id: u8, map: u8 },
        Group,
        Regroup { at: u8, len: u8 },
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            4 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Insert { robot, id, map }),
            1 => (0..3u8, 0..30u8).prop_map(|(robot, id)| Step::Remove { robot, id }),
            1 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Move { robot, id, map }),
            1 => Just(Step::Group),
            1 => (0..120u8, 0..40u8).prop_map(|(at, len)| Step::Regroup { at, len }),
        ]
    }

    proptest! {
        /// Any sequence of inserts, erasures, map moves, groupings and
        /// sortings of any range of rows leaves the same keyframes, links and tracks as the same
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
                    Step::Regroup { at, len } => {
                        let from = usize::from(at).min(grouped.len());
                        let to = (from + usize::from(len)).min(grouped.len());
                        grouped.sort_rows(from, to);
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
