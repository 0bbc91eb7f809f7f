//! f32 rows in a file of their own, read and written in place: where the
//! descriptor matrix keeps its rows when they are not held in memory.
//!
//! The compressed scan reads every row's one-byte code but only a few
//! thousand f32 rows per query (the re-scored candidates and the null
//! sample), so at fleet scale the f32 rows need not be resident: the
//! operating system's page cache serves the rows that are read, and they
//! do not count in the process's resident memory. Reads and writes are
//! positional (`pread`/`pwrite`), not a memory map, for that reason: a
//! mapped page counts in the resident set once it has been touched, and a
//! scan touches all of them over time.
//!
//! The file is unnamed (`O_TMPFILE` where the file system has it): it holds
//! nothing that is not in the store, is rebuilt at every start, and
//! disappears with the process, a crash included.

use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// `rows` rows of `dim` f32 values, row `i` at byte `4·dim·i` of an
/// unnamed file.
#[derive(Debug)]
pub struct RowFile {
    file: File,
    dim: usize,
    rows: usize,
}

impl RowFile {
    /// An empty row file for rows of `dim` values, in directory `dir`
    /// (which should be on a disk, not a memory file system).
    pub fn create_in(dir: &Path, dim: usize) -> io::Result<RowFile> {
        assert!(dim > 0, "rows of no values");
        Ok(RowFile {
            file: tempfile::tempfile_in(dir)?,
            dim,
            rows: 0,
        })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether the file holds no rows.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Byte offset of row `i`.
    fn offset(&self, i: usize) -> u64 {
        (i * self.dim * 4) as u64
    }

    /// Appends whole rows (`rows.len()` a multiple of the dimension).
    pub fn append(&mut self, rows: &[f32]) -> io::Result<()> {
        let first = self.rows;
        self.write_at(first, rows)?;
        self.rows = first + rows.len() / self.dim;
        Ok(())
    }

    /// Overwrites the rows from `first` on with `rows`; they must lie within
    /// the file or end it.
    fn write_at(&self, first: usize, rows: &[f32]) -> io::Result<()> {
        assert!(
            rows.len().is_multiple_of(self.dim),
            "{} values are not rows of {}",
            rows.len(),
            self.dim
        );
        assert!(first <= self.rows, "row {first} beyond the end");
        self.file
            .write_all_at(bytemuck::cast_slice(rows), self.offset(first))
    }

    /// Overwrites the rows from `first` on, within the file.
    pub fn write(&mut self, first: usize, rows: &[f32]) -> io::Result<()> {
        assert!(
            first + rows.len() / self.dim <= self.rows,
            "rows {first}.. beyond the end"
        );
        self.write_at(first, rows)
    }

    /// Reads the rows from `first` on into `out` (whole rows, within the
    /// file).
    pub fn read(&self, first: usize, out: &mut [f32]) -> io::Result<()> {
        assert!(
            out.len().is_multiple_of(self.dim) && first + out.len() / self.dim <= self.rows,
            "rows {first}.. ({} values) beyond the end",
            out.len()
        );
        self.file
            .read_exact_at(bytemuck::cast_slice_mut(out), self.offset(first))
    }

    /// Keeps the first `rows` rows.
    pub fn truncate(&mut self, rows: usize) -> io::Result<()> {
        assert!(rows <= self.rows, "truncating {} rows to {rows}", self.rows);
        self.file.set_len(self.offset(rows))?;
        self.rows = rows;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_read_back_as_written() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = RowFile::create_in(dir.path(), 2).unwrap();
        assert!(f.is_empty());
        f.append(&[1.0, 2.0, 3.0, 4.0]).unwrap();
        f.append(&[5.0, 6.0]).unwrap();
        assert_eq!(f.len(), 3);
        let mut out = [0.0; 4];
        f.read(1, &mut out).unwrap();
        assert_eq!(out, [3.0, 4.0, 5.0, 6.0]);
        f.write(0, &[-1.0, -2.0]).unwrap();
        f.truncate(2).unwrap();
        let mut all = [0.0; 4];
        f.read(0, &mut all).unwrap();
        assert_eq!(all, [-1.0, -2.0, 3.0, 4.0]);
        // The file is unnamed: nothing is left in the directory.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    #[should_panic(expected = "beyond the end")]
    fn reading_past_the_end_panics() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = RowFile::create_in(dir.path(), 2).unwrap();
        f.append(&[1.0, 2.0]).unwrap();
        f.read(1, &mut [0.0; 2]).unwrap();
    }
}
