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
//! ([`Index::apply_tail_grouping`]). Each grouped tail then holds one run per
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
//! corrected poses may move a keyframe to another map in place; the rows so
//! displaced stay where they are (a grouping sorts only the rows appended
//! since the last one). A replaced keyframe is such an erasure plus an
//! append, so under replacements alone the tail keeps its length and is
//! not grouped again.

use super::{Index, NO_ROW};
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::matrix::MatrixRows;

/// Rows appended since the last grouping from which
/// [`Index::group_tail_if_due`] groups them.
pub const GROUP_TAIL_ROWS: usize = 4096;

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

    /// Sorts the rows appended since the last grouping by (robot,
    /// session, map, keyframe id), everything row-aligned moving with
    /// them, and returns how many there were. Rows before them stay where
    /// they are. [`Index::plan_tail_grouping`] then
    /// [`Index::apply_tail_grouping`], for an index no one else reads.
    pub fn group_tail(&mut self) -> usize {
        match self.plan_tail_grouping() {
            Some(plan) => self.apply_tail_grouping(plan),
            None => 0,
        }
    }

    /// The first half of [`Index::group_tail`], which only reads: the
    /// tail's new order and copies of its descriptors, codes and
    /// thumbnails in that order, the bulk of the work, so that queries go
    /// on meanwhile under a shared lock. `None` without a tail.
    pub fn plan_tail_grouping(&self) -> Option<TailGrouping> {
        let from = self.grouped.min(self.rows.len());
        let len = self.rows.len();
        if from == len {
            return None;
        }
        let mut order: Vec<usize> = (from..len).collect();
        order.sort_unstable_by_key(|&row| {
            let ids = &self.ids[row];
            (ids.robot, ids.session, ids.map_id, ids.keyframe_id)
        });
        Some(TailGrouping {
            from,
            changes: self.changes,
            matrix: self.matrix.gathered(&order),
            appearance: self.appearance.gathered(&order),
            order,
        })
    }

    /// The second half of [`Index::group_tail`]: puts the planned rows in
    /// place (one copy each of the descriptors, codes and thumbnails), moves
    /// the row tables and fixes every link to a moved row. Returns the
    /// rows moved, or 0, doing nothing, if the index changed since the
    /// plan was made.
    pub fn apply_tail_grouping(&mut self, plan: TailGrouping) -> usize {
        let TailGrouping {
            from,
            changes,
            order,
            matrix,
            appearance,
        } = plan;
        let len = self.rows.len();
        if changes != self.changes || from + order.len() != len {
            return 0;
        }
        // new_row[old − from]: where each tail row goes.
        let mut new_row = vec![0usize; order.len()];
        for (i, &old) in order.iter().enumerate() {
            new_row[old - from] = from + i;
        }
        self.matrix.overwrite_tail(from, matrix);
        self.appearance.overwrite_tail(from, appearance);
        permute_tail(&mut self.rows, from, &order);
        permute_tail(&mut self.ids, from, &order);
        permute_tail(&mut self.preds, from, &order);
        permute_tail(&mut self.tags, from, &order);
        // A predecessor anywhere may be a tail row: every link is checked.
        for pred in &mut self.preds {
            let p = *pred as usize;
            if *pred != NO_ROW && p >= from {
                *pred = new_row[p - from] as u32;
            }
        }
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
        self.grouped = len;
        self.layout_epoch += 1;
        self.changes += 1;
        len - from
    }
}

/// A grouping of an index's tail, planned and not yet applied (see
/// [`Index::plan_tail_grouping`]).
#[derive(Debug)]
pub struct TailGrouping {
    from: usize,
    /// The index's change count when planned.
    changes: u64,
    /// The old row of each new tail position.
    order: Vec<usize>,
    matrix: MatrixRows,
    appearance: AppearanceMatrix,
}

/// Reorders `values[from..]` so that position `from + i` holds the old
/// `values[order[i]]`, moving the values (no clone).
fn permute_tail<T>(values: &mut Vec<T>, from: usize, order: &[usize]) {
    assert_eq!(
        from + order.len(),
        values.len(),
        "not a permutation of the tail"
    );
    let mut old: Vec<Option<T>> = values.drain(from..).map(Some).collect();
    values.extend(
        order
            .iter()
            .map(|&row| old[row - from].take().expect("each row once")),
    );
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
        assert_eq!(index.apply_tail_grouping(plan), 0);
        check(&index);
        assert_eq!(contents(&index), before);
        assert_eq!((index.ungrouped_rows(), index.layout_epoch()), (21, 0));
        let plan = index.plan_tail_grouping().unwrap();
        assert_eq!(index.apply_tail_grouping(plan), 21);
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
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            4 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Insert { robot, id, map }),
            1 => (0..3u8, 0..30u8).prop_map(|(robot, id)| Step::Remove { robot, id }),
            1 => (0..3u8, 0..30u8, 0..2u8).prop_map(|(robot, id, map)| Step::Move { robot, id, map }),
            1 => Just(Step::Group),
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
