//! What a scan asks of the eligibility rule: a test per row, and which rows
//! can pass at all.
//!
//! The rule itself is [`eligibility`](crate::vpr::eligibility) (compiled for the
//! index in `row_ids`). A scan needs only to test a row; but to cost what a
//! query may return rather than the whole store, it must also know where
//! the rows that can pass are. A filter that knows (the index's, from its
//! per-map tracks) names them as a *partition*, and the scan visits only
//! those; a plain closure names none, and the scan visits every row. Either
//! way the answer is the same: the partition only leaves out rows the test
//! refuses.
//!
//! Where the rows that can pass all belong to one map, the filter names it
//! too ([`RowFilter::group`]), so that a memory that keeps a neighbour
//! graph per map can walk that map's graph instead of filtering the whole
//! store's.

/// Which stored rows a query may be answered from.
pub trait RowFilter: Sync {
    /// Whether `row` may be proposed.
    fn test(&self, row: usize) -> bool;

    /// The rows outside of which [`RowFilter::test`] is false, sorted
    /// ascending; `None`: any row may pass, so a scan visits every row.
    /// A row's temporal predecessors must be in it whenever the row is (the
    /// index's partitions are whole maps, and a track never leaves its
    /// map); a scan that finds one missing still scores it, only slower.
    fn partition(&self) -> Option<&[usize]> {
        None
    }

    /// Calls `f` with every row of the [partition](RowFilter::partition)
    /// whose sample tag (`tag(row)`) has no bit of `mask` set, in no
    /// particular order and without gathering the partition where the
    /// filter can avoid it (the index keeps each large map's sampled rows
    /// apart); false (and `f` never called) where it names none.
    fn for_each_tagged_in_partition(
        &self,
        mask: u32,
        tag: &dyn Fn(usize) -> u32,
        f: &mut dyn FnMut(usize),
    ) -> bool {
        match self.partition() {
            Some(rows) => {
                for_each_tagged(rows.iter().copied(), mask, tag, f);
                true
            }
            None => false,
        }
    }

    /// How many rows can pass at most (the rows of the maps the rule
    /// admits), where the filter knows it cheaply; None: unknown. What a
    /// planner weighs the exact pass's cost by.
    fn admitted(&self) -> Option<usize> {
        self.partition().map(<[usize]>::len)
    }

    /// The one group of rows every row that can pass belongs to, as the
    /// memory that compiled the filter numbers its groups (the index: one
    /// map); None where there is no such group or the filter does not know.
    fn group(&self) -> Option<RowGroup> {
        None
    }
}

/// A group of rows as a memory numbers them (the index's: one map, by its
/// interned session and its map id). Only the memory that compiled a
/// filter reads it.
pub type RowGroup = u128;

impl<F: Fn(usize) -> bool + Sync + ?Sized> RowFilter for F {
    fn test(&self, row: usize) -> bool {
        self(row)
    }
}

/// Calls `f` with each of `rows` whose tag (`tag(row)`) has no bit of
/// `mask` set.
pub fn for_each_tagged(
    rows: impl Iterator<Item = usize>,
    mask: u32,
    tag: &dyn Fn(usize) -> u32,
    f: &mut dyn FnMut(usize),
) {
    rows.filter(|&row| tag(row) & mask == 0).for_each(f);
}
