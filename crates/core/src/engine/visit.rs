//! Which rows a scan visits and in what pieces: every stored row, a span
//! of them, or the sorted rows of a filter's partition, cut into blocks for the cores and
//! each block into runs of consecutive rows (so rows kept in a file are
//! read in one call a run).

/// The rows a pass visits, by position: every stored row, or the sorted
/// rows of a filter's partition.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Visit<'a> {
    /// Rows `0..n`.
    All(usize),
    /// `len` rows from `first` on (one piece of a pass over a large store).
    Span(usize, usize),
    /// These rows, ascending.
    Only(&'a [usize]),
}

impl<'a> Visit<'a> {
    /// Rows visited.
    pub(crate) fn len(&self) -> usize {
        match self {
            Visit::All(n) => *n,
            Visit::Span(_, len) => *len,
            Visit::Only(rows) => rows.len(),
        }
    }

    /// The position of `row` in the visit, if it is one of its rows.
    #[inline]
    pub(crate) fn position(&self, row: usize) -> Option<usize> {
        match self {
            Visit::All(n) => (row < *n).then_some(row),
            Visit::Span(first, len) => row.checked_sub(*first).filter(|i| i < len),
            Visit::Only(rows) => rows.binary_search(&row).ok(),
        }
    }

    /// The rows at positions `first..first + len`.
    pub(crate) fn block(&self, first: usize, len: usize) -> Block<'a> {
        match self {
            Visit::All(_) => Block::Range(first, len),
            Visit::Span(start, _) => Block::Range(start + first, len),
            Visit::Only(rows) => Block::Rows(&rows[first..first + len]),
        }
    }
}

/// The rows of one block of a [`Visit`].
#[derive(Debug, Clone, Copy)]
pub(crate) enum Block<'a> {
    /// `len` rows from `first` on.
    Range(usize, usize),
    /// These rows, ascending.
    Rows(&'a [usize]),
}

impl Block<'_> {
    /// The block's `i`-th row.
    #[inline]
    pub(crate) fn row(&self, i: usize) -> usize {
        match self {
            Block::Range(first, _) => first + i,
            Block::Rows(rows) => rows[i],
        }
    }

    /// The block's runs of consecutive rows: `(position, first row, rows)`.
    pub(crate) fn runs(&self) -> Vec<(usize, usize, usize)> {
        match self {
            Block::Range(first, len) => vec![(0, *first, *len)],
            Block::Rows(rows) => {
                let mut runs: Vec<(usize, usize, usize)> = Vec::new();
                for (i, &row) in rows.iter().enumerate() {
                    match runs.last_mut() {
                        Some((_, first, len)) if *first + *len == row => *len += 1,
                        _ => runs.push((i, row, 1)),
                    }
                }
                runs
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_partition_is_visited_in_runs_of_consecutive_rows() {
        let rows = [2, 3, 4, 9, 11, 12];
        let visit = Visit::Only(&rows);
        assert_eq!(visit.len(), 6);
        assert_eq!(visit.position(9), Some(3));
        assert_eq!(visit.position(5), None);
        let block = visit.block(1, 4);
        assert_eq!(block.row(0), 3);
        assert_eq!(block.runs(), vec![(0, 3, 2), (2, 9, 1), (3, 11, 1)]);
        let all = Visit::All(10);
        assert_eq!(all.position(9), Some(9));
        assert_eq!(all.position(10), None);
        assert_eq!(all.block(4, 3).runs(), vec![(0, 4, 3)]);
    }

    #[test]
    fn a_span_is_visited_from_its_first_row() {
        let span = Visit::Span(100, 20);
        assert_eq!(span.len(), 20);
        assert_eq!(span.position(100), Some(0));
        assert_eq!(span.position(119), Some(19));
        assert_eq!(span.position(99), None);
        assert_eq!(span.position(120), None);
        let block = span.block(5, 10);
        assert_eq!(block.row(0), 105);
        assert_eq!(block.runs(), vec![(0, 105, 10)]);
    }
}
