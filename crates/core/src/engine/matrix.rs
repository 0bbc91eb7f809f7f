//! The contiguous descriptor matrix that SCAL scans, and its dot product.
//!
//! SCAL is one pass over N descriptors of dimension d, bound by memory
//! bandwidth. Rows are therefore stored row-major in a single `Vec<f32>` (no
//! per-row allocation, no pointer chasing), removal is `swap_remove` so the
//! storage stays dense, and [`dot`] sums in eight independent lanes (see
//! [`crate::engine::kernels::f32_lane_sums`]: AVX where the CPU has it, a
//! plain loop compiled per instruction set elsewhere; the order of the
//! additions, and so the result, is the same on every CPU).
//!
//! The matrix keeps the one-byte [`CodeMatrix`] of its rows in step with
//! them, so that large stores can be scanned on the codes first; a store
//! that is scanned on its codes reads few f32 rows per query, so those can
//! move to a [`RowFile`] and out of the resident memory.

use std::borrow::Cow;
use std::io;
use std::path::Path;

use crate::engine::codes::CodeMatrix;
use crate::engine::row_file::RowFile;

/// Row-major matrix of `len()` descriptors of dimension `dim()`.
///
/// The rows are in memory until [`DescriptorMatrix::move_to_file`] moves
/// them to a [`RowFile`]; the codes always stay in memory. Reading a row
/// then reads the file, so [`DescriptorMatrix::row`] and
/// [`DescriptorMatrix::rows`] hand out a copy instead of a borrow. The file
/// stands in for memory: an I/O error on it panics with the error, as a
/// failed allocation would abort (the store refuses inserts well before its
/// disk is full, see `store.min_free_bytes`).
#[derive(Debug, Default)]
pub struct DescriptorMatrix {
    dim: usize,
    rows: usize,
    data: Rows,
    codes: CodeMatrix,
}

/// Some rows of a [`DescriptorMatrix`] with their codes, copied out of it
/// ([`DescriptorMatrix::gathered`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MatrixRows {
    values: Vec<f32>,
    codes: crate::engine::codes::CodeRows,
}

/// Where the f32 rows are.
#[derive(Debug)]
enum Rows {
    Memory(Vec<f32>),
    File(RowFile),
}

impl Default for Rows {
    fn default() -> Self {
        Rows::Memory(Vec::new())
    }
}

/// Rows moved or copied per I/O call.
const IO_ROWS: usize = 4096;

/// Panics for a failed read or write of the row file (see
/// [`DescriptorMatrix`]).
fn row_file_failed(what: &str, error: io::Error) -> ! {
    panic!("the descriptor row file failed to {what}: {error}")
}

impl Clone for DescriptorMatrix {
    /// A copy in memory, wherever this matrix keeps its rows.
    fn clone(&self) -> Self {
        DescriptorMatrix {
            dim: self.dim,
            rows: self.rows,
            data: Rows::Memory(self.rows(0, self.rows).into_owned()),
            codes: self.codes.clone(),
        }
    }
}

impl PartialEq for DescriptorMatrix {
    /// Same dimension and rows, wherever each keeps them.
    fn eq(&self, other: &Self) -> bool {
        self.dim == other.dim
            && self.rows == other.rows
            && self.rows(0, self.rows) == other.rows(0, other.rows)
    }
}

impl DescriptorMatrix {
    /// An empty matrix for descriptors of dimension `dim`.
    pub fn new(dim: usize) -> Self {
        DescriptorMatrix {
            dim,
            rows: 0,
            data: Rows::default(),
            codes: CodeMatrix::new(dim),
        }
    }

    /// A matrix holding `data` as rows of `dim` values (row-major), with
    /// their codes; for loading a stored matrix in one piece. Panics if
    /// `data.len()` is not a multiple of `dim`.
    pub fn from_rows(dim: usize, data: Vec<f32>) -> Self {
        assert!(
            dim > 0 && data.len().is_multiple_of(dim),
            "{} values are not rows of {dim}",
            data.len()
        );
        let codes = CodeMatrix::from_rows(dim, &data);
        DescriptorMatrix {
            dim,
            rows: data.len() / dim,
            data: Rows::Memory(data),
            codes,
        }
    }

    /// A matrix of the rows in `file`, whose `codes` the caller computed
    /// from them (as when the rows were read once to check them). Panics
    /// if the two differ in length.
    pub fn from_row_file(dim: usize, file: RowFile, codes: CodeMatrix) -> Self {
        assert_eq!(file.len(), codes.len(), "codes for other rows");
        DescriptorMatrix {
            dim,
            rows: file.len(),
            data: Rows::File(file),
            codes,
        }
    }

    /// The matrix without the rows listed in `skip` (ascending), the
    /// others in order, in memory.
    pub fn without_rows(self, skip: &[usize]) -> Self {
        let mut skip = skip.iter().peekable();
        let mut data = Vec::with_capacity((self.rows - skip.len()) * self.dim);
        for first in (0..self.rows).step_by(IO_ROWS) {
            let block = self.rows(first, IO_ROWS.min(self.rows - first));
            for (i, row) in block.chunks_exact(self.dim).enumerate() {
                if skip.next_if_eq(&&(first + i)).is_none() {
                    data.extend_from_slice(row);
                }
            }
        }
        DescriptorMatrix::from_rows(self.dim, data)
    }

    /// Descriptor dimension `d`.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of rows `N`.
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether the matrix has no rows.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Whether the f32 rows are in memory (not moved to a file).
    pub fn in_memory(&self) -> bool {
        matches!(self.data, Rows::Memory(_))
    }

    /// Moves the f32 rows to an unnamed [`RowFile`] in `dir` and frees
    /// their memory; rows added later go to the file too. Nothing changes
    /// if they are in a file already, while the dimension is unknown (0),
    /// or on an error.
    pub fn move_to_file(&mut self, dir: &Path) -> io::Result<()> {
        let Rows::Memory(data) = &mut self.data else {
            return Ok(());
        };
        if self.dim == 0 {
            return Ok(());
        }
        let mut file = RowFile::create_in(dir, self.dim)?;
        for block in data.chunks(IO_ROWS * self.dim) {
            file.append(block)?;
        }
        self.data = Rows::File(file);
        Ok(())
    }

    /// Appends a row and returns its index. Panics if `row.len() != dim()`
    /// (callers validate descriptors first).
    pub fn push(&mut self, row: &[f32]) -> usize {
        assert_eq!(row.len(), self.dim, "descriptor dimension mismatch");
        match &mut self.data {
            Rows::Memory(data) => data.extend_from_slice(row),
            Rows::File(file) => file
                .append(row)
                .unwrap_or_else(|e| row_file_failed("append a row", e)),
        }
        self.codes.push(row);
        self.rows += 1;
        self.rows - 1
    }

    /// Asks the CPU to start loading row `i` into its caches (rows in
    /// memory on x86-64; otherwise nothing). A scan over scattered rows (a
    /// query's partition: one row of a robot every few dozen) issues it a
    /// few rows ahead, since each such row is a fresh page the hardware
    /// prefetcher does not foresee, and without it the rows wait for
    /// memory one after another. Panics if out of range.
    pub fn prefetch_row(&self, i: usize) {
        assert!(i < self.rows, "row {i} out of range");
        if let Rows::Memory(data) = &self.data {
            crate::numeric::prefetch(&data[i * self.dim..(i + 1) * self.dim]);
        }
    }

    /// Row `i`: borrowed when in memory, read when in a file. Panics if out
    /// of range.
    pub fn row(&self, i: usize) -> Cow<'_, [f32]> {
        assert!(i < self.rows, "row {i} out of range");
        self.rows(i, 1)
    }

    /// `count` rows from row `first` on, row-major: borrowed when in
    /// memory, read in one call when in a file. Panics if out of range.
    pub fn rows(&self, first: usize, count: usize) -> Cow<'_, [f32]> {
        assert!(
            first + count <= self.rows,
            "rows {first}..{} out of range",
            first + count
        );
        let range = first * self.dim..(first + count) * self.dim;
        match &self.data {
            Rows::Memory(data) => Cow::Borrowed(&data[range]),
            Rows::File(file) => {
                let mut out = vec![0.0; range.len()];
                if !out.is_empty() {
                    file.read(first, &mut out)
                        .unwrap_or_else(|e| row_file_failed("read rows", e));
                }
                Cow::Owned(out)
            }
        }
    }

    /// Overwrites row `i`. Panics if out of range or on a dimension mismatch.
    pub fn set_row(&mut self, i: usize, row: &[f32]) {
        assert!(i < self.rows, "row {i} out of range");
        assert_eq!(row.len(), self.dim, "descriptor dimension mismatch");
        match &mut self.data {
            Rows::Memory(data) => data[i * self.dim..(i + 1) * self.dim].copy_from_slice(row),
            Rows::File(file) => file
                .write(i, row)
                .unwrap_or_else(|e| row_file_failed("write a row", e)),
        }
        self.codes.set_row(i, row);
    }

    /// The one-byte codes of the rows, row-aligned.
    pub fn codes(&self) -> &CodeMatrix {
        &self.codes
    }

    /// Removes row `i` by moving the last row into its place (like
    /// `Vec::swap_remove`). Panics if out of range.
    pub fn swap_remove(&mut self, i: usize) {
        assert!(i < self.rows, "row {i} out of range");
        let last = self.rows - 1;
        match &mut self.data {
            Rows::Memory(data) => {
                if i != last {
                    let (head, tail) = data.split_at_mut(last * self.dim);
                    head[i * self.dim..(i + 1) * self.dim].copy_from_slice(tail);
                }
                data.truncate(last * self.dim);
            }
            Rows::File(file) => {
                let moved = (|| {
                    if i != last {
                        let mut row = vec![0.0; self.dim];
                        file.read(last, &mut row)?;
                        file.write(i, &row)?;
                    }
                    file.truncate(last)
                })();
                moved.unwrap_or_else(|e| row_file_failed("move a row", e));
            }
        }
        self.codes.swap_remove(i);
        self.rows = last;
    }

    /// Copies of the rows `order` lists, in that order, with their codes:
    /// the half of a reordering that only reads, so that it can run under
    /// a shared lock ([`DescriptorMatrix::overwrite_rows`] is the other).
    /// Rows in a file are read in one call a run of consecutive rows.
    pub fn gathered(&self, order: &[usize]) -> MatrixRows {
        let dim = self.dim;
        let mut values = Vec::with_capacity(order.len() * dim);
        let mut i = 0;
        while i < order.len() {
            let mut run = 1;
            while i + run < order.len() && order[i + run] == order[i] + run {
                run += 1;
            }
            values.extend_from_slice(&self.rows(order[i], run));
            i += run;
        }
        MatrixRows {
            values,
            codes: self.codes.gathered(order),
        }
    }

    /// Replaces the rows from `from` on with `rows` (as many as there are,
    /// gathered from this matrix), in memory or in the row file.
    pub fn overwrite_rows(&mut self, from: usize, rows: MatrixRows) {
        let count = rows.values.len() / self.dim.max(1);
        assert!(from + count <= self.rows, "rows past the end");
        match &mut self.data {
            Rows::Memory(data) => {
                data[from * self.dim..(from + count) * self.dim].copy_from_slice(&rows.values)
            }
            Rows::File(file) => file
                .write(from, &rows.values)
                .unwrap_or_else(|e| row_file_failed("reorder rows", e)),
        }
        self.codes.overwrite_rows(from, rows.codes);
    }

    /// Removes every row, keeping the dimension and where the rows live.
    pub fn clear(&mut self) {
        match &mut self.data {
            Rows::Memory(data) => data.clear(),
            Rows::File(file) => file
                .truncate(0)
                .unwrap_or_else(|e| row_file_failed("truncate", e)),
        }
        self.codes.clear();
        self.rows = 0;
    }
}

/// `aᵀb` over the common prefix of `a` and `b` (they have equal length in
/// practice): [`multi_dot`] with one query, so that a product computed on
/// its own and in a scan are the same bits.
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let [d] = multi_dot(&[a], b);
    d
}

/// `[q₀ᵀrow, q₁ᵀrow, …]`: the dot products of one row with `Q` queries,
/// reading the row from memory once. SCAL compares every stored row with
/// the query and its predecessors; fusing those products into one pass
/// over the matrix keeps the scan bound by one read of memory instead of
/// `Q`.
pub fn multi_dot<const Q: usize>(queries: &[&[f32]; Q], row: &[f32]) -> [f32; Q] {
    let n = queries.iter().fold(row.len(), |n, q| n.min(q.len()));
    let full = n - n % 8;
    let acc = crate::engine::kernels::f32_lane_sums(queries, row, full);
    let mut out = [0.0f32; Q];
    for ((o, sums), q) in out.iter_mut().zip(&acc).zip(queries) {
        let tail: f32 = q[full..n]
            .iter()
            .zip(&row[full..n])
            .map(|(x, y)| x * y)
            .sum();
        let pairs = [
            sums[0] + sums[4],
            sums[1] + sums[5],
            sums[2] + sums[6],
            sums[3] + sums[7],
        ];
        *o = (pairs[0] + pairs[2]) + (pairs[1] + pairs[3]) + tail;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs::File;

    #[test]
    fn multi_dot_equals_separate_dots() {
        for dim in [1, 7, 8, 9, 64, 133] {
            let row: Vec<f32> = (0..dim).map(|i| (i as f32 * 0.37).sin()).collect();
            let q0: Vec<f32> = (0..dim).map(|i| (i as f32 * 0.11).cos()).collect();
            let q1: Vec<f32> = (0..dim).map(|i| 1.0 / (1.0 + i as f32)).collect();
            let [a, b] = multi_dot(&[&q0, &q1], &row);
            assert_eq!(a, dot(&q0, &row), "dim {dim}");
            assert_eq!(b, dot(&q1, &row), "dim {dim}");
        }
    }

    #[test]
    fn push_row_set_row() {
        let mut m = DescriptorMatrix::new(3);
        assert!(m.is_empty());
        assert_eq!(m.push(&[1.0, 2.0, 3.0]), 0);
        assert_eq!(m.push(&[4.0, 5.0, 6.0]), 1);
        assert_eq!(m.len(), 2);
        assert_eq!(m.dim(), 3);
        assert_eq!(&*m.row(1), &[4.0, 5.0, 6.0]);
        m.set_row(0, &[7.0, 8.0, 9.0]);
        assert_eq!(&*m.row(0), &[7.0, 8.0, 9.0]);
    }

    #[test]
    fn swap_remove_moves_the_last_row() {
        let mut m = DescriptorMatrix::new(2);
        for i in 0..4 {
            m.push(&[i as f32, 10.0 + i as f32]);
        }
        m.swap_remove(1);
        assert_eq!(m.len(), 3);
        assert_eq!(&*m.row(0), &[0.0, 10.0]);
        assert_eq!(&*m.row(1), &[3.0, 13.0]);
        assert_eq!(&*m.row(2), &[2.0, 12.0]);
        // Removing the last row just truncates.
        m.swap_remove(2);
        assert_eq!(m.len(), 2);
        assert_eq!(&*m.row(1), &[3.0, 13.0]);
        m.clear();
        assert!(m.is_empty());
        assert_eq!(m.dim(), 2);
    }

    /// The same changes on a matrix in memory, one moved to a row file and
    /// one over rows stored in another file.
    #[test]
    fn rows_in_a_file_behave_as_rows_in_memory() {
        let dir = tempfile::tempdir().unwrap();
        let mut memory = DescriptorMatrix::new(3);
        let mut file = DescriptorMatrix::new(3);
        for i in 0..5 {
            let row = [i as f32, 1.0, -(i as f32)];
            memory.push(&row);
            file.push(&row);
        }
        file.move_to_file(dir.path()).unwrap();
        assert!(!file.in_memory() && memory.in_memory());
        assert_eq!(file, memory);
        let base = dir.path().join("base");
        std::fs::write(&base, bytemuck::cast_slice::<f32, u8>(&memory.rows(0, 5))).unwrap();
        let rows = RowFile::over(File::open(&base).unwrap(), 0, 5, dir.path(), 3).unwrap();
        let mut over = DescriptorMatrix::from_row_file(3, rows, memory.codes().clone());
        assert_eq!(over, memory);
        for m in [&mut memory, &mut file, &mut over] {
            m.push(&[9.0, 9.0, 9.0]);
            m.set_row(1, &[7.0, 8.0, 9.0]);
            m.swap_remove(0);
            m.swap_remove(4);
        }
        assert_eq!(file, memory);
        assert_eq!(over, memory);
        assert_eq!(file.codes(), memory.codes());
        assert_eq!(over.codes(), memory.codes());
        assert_eq!(&*file.row(0), &[9.0, 9.0, 9.0]);
        assert_eq!(&*file.rows(1, 2), &*memory.rows(1, 2));
        assert!(file.clone().in_memory(), "a clone is in memory");
        let kept = file.without_rows(&[0, 2]);
        assert_eq!(&*kept.rows(0, 2), &[7.0, 8.0, 9.0, 3.0, 1.0, -3.0]);
        memory.clear();
        assert!(memory.is_empty());
    }

    #[test]
    #[should_panic]
    fn push_rejects_wrong_dimension() {
        DescriptorMatrix::new(3).push(&[1.0]);
    }

    #[test]
    fn dot_matches_the_naive_sum() {
        // Lengths around the chunk size exercise the remainder path.
        for n in [0usize, 1, 7, 8, 9, 16, 17, 512, 515] {
            let a: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
            let b: Vec<f32> = (0..n).map(|i| (i as f32 * 0.11).cos()).collect();
            let naive: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            assert!((dot(&a, &b) as f64 - naive).abs() < 1e-3, "n = {n}");
        }
        // 1·4 + 2·5 + 3·6 = 32.
        assert_eq!(dot(&[1.0, 2.0, 3.0], &[4.0, 5.0, 6.0]), 32.0);
    }
}
