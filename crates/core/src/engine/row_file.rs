//! f32 rows kept in files instead of memory, read and written in place:
//! where the descriptor matrix keeps its rows when they are not resident.
//!
//! The compressed scan reads every row's one-byte code but only a few
//! thousand f32 rows per query (the re-scored candidates and the null
//! sample), so at fleet scale the f32 rows need not be resident: the
//! operating system's page cache serves the rows that are read, and they
//! do not count in the process's resident memory. Reads and writes are
//! positional (`pread`/`pwrite`), not a memory map, for that reason: a
//! mapped page counts in the resident set once it has been touched, and
//! scans touch all of them over time.
//!
//! Rows can start out as a read-only *base*: a range of an existing file,
//! such as the descriptor section of the index snapshot the store opened
//! from, so that opening a large store does not copy gigabytes into a new
//! file (on the development machine that copy alone took 5 s per 2 GB).
//! Rows past the base, and base rows overwritten later (a *patch*), go to
//! two unnamed files of the row file's own (`O_TMPFILE` where the file
//! system has it): they hold nothing that is not in the store, and
//! disappear with the process, a crash included. A patch slot is reused
//! when its row is overwritten again, so patches never outnumber base rows.

use std::collections::BTreeMap;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// `len()` rows of `dim` f32 values.
#[derive(Debug)]
pub struct RowFile {
    dim: usize,
    rows: usize,
    /// Rows `0..base_rows` are read from here, unless patched.
    base: Option<Base>,
    base_rows: usize,
    /// Row `base_rows + i` at byte `4·dim·i`.
    tail: File,
    /// Rows the tail file has room for (its length), at least the rows in
    /// it: see [`RowFile::truncate`].
    tail_capacity: usize,
    /// Overwritten base rows: row → slot in `patches`.
    patched: BTreeMap<usize, usize>,
    patches: File,
    patch_slots: usize,
}

/// A read-only range of rows in an existing file.
#[derive(Debug)]
struct Base {
    file: File,
    /// Byte offset of row 0.
    offset: u64,
}

impl RowFile {
    /// An empty row file for rows of `dim` values, its files in directory
    /// `dir` (which should be on a disk, not a memory file system).
    pub fn create_in(dir: &Path, dim: usize) -> io::Result<RowFile> {
        assert!(dim > 0, "rows of no values");
        Ok(RowFile {
            dim,
            rows: 0,
            base: None,
            base_rows: 0,
            tail: tempfile::tempfile_in(dir)?,
            tail_capacity: 0,
            patched: BTreeMap::new(),
            patches: tempfile::tempfile_in(dir)?,
            patch_slots: 0,
        })
    }

    /// A row file whose first `rows` rows are those stored in `file` from
    /// byte `offset` on, row-major, which must not change while this
    /// lives (an open file that is replaced by a rename keeps its data);
    /// they are never written. Its own files go in `dir`.
    pub fn over(
        file: File,
        offset: u64,
        rows: usize,
        dir: &Path,
        dim: usize,
    ) -> io::Result<RowFile> {
        let mut row_file = RowFile::create_in(dir, dim)?;
        row_file.base = Some(Base { file, offset });
        row_file.base_rows = rows;
        row_file.rows = rows;
        Ok(row_file)
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether the file holds no rows.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Bytes of `rows` rows.
    fn bytes(&self, rows: usize) -> u64 {
        (rows * self.dim * 4) as u64
    }

    /// Appends whole rows (`rows.len()` a multiple of the dimension).
    pub fn append(&mut self, rows: &[f32]) -> io::Result<()> {
        self.check_whole(rows.len());
        let first = self.rows;
        self.rows = first + rows.len() / self.dim;
        let written = self.write_range(first, rows);
        if written.is_err() {
            self.rows = first;
        }
        written
    }

    /// Overwrites the rows from `first` on with `rows`, within the file.
    pub fn write(&mut self, first: usize, rows: &[f32]) -> io::Result<()> {
        self.check_whole(rows.len());
        assert!(
            first + rows.len() / self.dim <= self.rows,
            "rows {first}.. beyond the end"
        );
        self.write_range(first, rows)
    }

    /// Writes rows from `first` on: base rows as patches, the others in
    /// the tail.
    fn write_range(&mut self, first: usize, rows: &[f32]) -> io::Result<()> {
        let in_base = self
            .base_rows
            .saturating_sub(first)
            .min(rows.len() / self.dim);
        for (i, row) in rows.chunks_exact(self.dim).take(in_base).enumerate() {
            let next = self.patch_slots;
            let slot = *self.patched.entry(first + i).or_insert(next);
            self.patches
                .write_all_at(bytemuck::cast_slice(row), self.bytes(slot))?;
            self.patch_slots = self.patch_slots.max(slot + 1);
        }
        let tail = &rows[in_base * self.dim..];
        if tail.is_empty() {
            return Ok(());
        }
        let at = first + in_base - self.base_rows;
        self.tail
            .write_all_at(bytemuck::cast_slice(tail), self.bytes(at))?;
        self.tail_capacity = self.tail_capacity.max(at + tail.len() / self.dim);
        Ok(())
    }

    /// Reads the rows from `first` on into `out` (whole rows, within the
    /// file): each run of unpatched base rows in one call, each patched
    /// row from its patch (never both), the tail in one call.
    pub fn read(&self, first: usize, out: &mut [f32]) -> io::Result<()> {
        self.check_whole(out.len());
        let count = out.len() / self.dim;
        assert!(
            first + count <= self.rows,
            "rows {first}..{} beyond the end",
            first + count
        );
        let in_base = self.base_rows.saturating_sub(first).min(count);
        if let (Some(base), true) = (&self.base, in_base > 0) {
            let (head, _) = out.split_at_mut(in_base * self.dim);
            let values = |rows: std::ops::Range<usize>| {
                (rows.start - first) * self.dim..(rows.end - first) * self.dim
            };
            let read_base = |rows: std::ops::Range<usize>, head: &mut [f32]| {
                if rows.is_empty() {
                    return Ok(());
                }
                let at = base.offset + self.bytes(rows.start);
                base.file
                    .read_exact_at(bytemuck::cast_slice_mut(&mut head[values(rows)]), at)
            };
            let mut next = first;
            for (&row, &slot) in self.patched.range(first..first + in_base) {
                read_base(next..row, head)?;
                self.patches.read_exact_at(
                    bytemuck::cast_slice_mut(&mut head[values(row..row + 1)]),
                    self.bytes(slot),
                )?;
                next = row + 1;
            }
            read_base(next..first + in_base, head)?;
        }
        let tail = &mut out[in_base * self.dim..];
        if tail.is_empty() {
            return Ok(());
        }
        let at = first + in_base - self.base_rows;
        self.tail
            .read_exact_at(bytemuck::cast_slice_mut(tail), self.bytes(at))
    }

    /// Keeps the first `rows` rows. The tail file keeps its length while
    /// at least half of it is in use: a replaced keyframe is a
    /// swap-remove then an append, and overwriting the same bytes costs
    /// less than giving blocks back to the file system and taking them
    /// again on every insert.
    pub fn truncate(&mut self, rows: usize) -> io::Result<()> {
        assert!(rows <= self.rows, "truncating {} rows to {rows}", self.rows);
        if rows < self.base_rows {
            // The base shrinks; patches of the rows let go are dropped
            // (their slots stay unused until the process ends).
            self.patched.split_off(&rows);
            self.base_rows = rows;
        }
        let tail_rows = rows - self.base_rows;
        if tail_rows < self.tail_capacity / 2 {
            self.tail.set_len(self.bytes(tail_rows))?;
            self.tail_capacity = tail_rows;
        }
        self.rows = rows;
        Ok(())
    }

    /// Panics unless `values` is a whole number of rows.
    fn check_whole(&self, values: usize) {
        assert!(
            values.is_multiple_of(self.dim),
            "{values} values are not rows of {}",
            self.dim
        );
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
        // The files are unnamed: nothing is left in the directory.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    /// A row file over a base behaves as a plain list of rows under every
    /// change, and never writes to its base.
    #[test]
    fn rows_over_a_base_behave_as_a_list() {
        let dir = tempfile::tempdir().unwrap();
        let dim = 3;
        let stored: Vec<f32> = (0..7 * dim).map(|v| v as f32).collect();
        let path = dir.path().join("base");
        let mut bytes = vec![0xAB; 5]; // rows start after a 5-byte header
        bytes.extend_from_slice(bytemuck::cast_slice(&stored));
        std::fs::write(&path, &bytes).unwrap();
        let base = File::open(&path).unwrap();
        let mut f = RowFile::over(base, 5, 7, dir.path(), dim).unwrap();
        let mut list: Vec<Vec<f32>> = stored.chunks(dim).map(<[f32]>::to_vec).collect();
        let check = |f: &RowFile, list: &[Vec<f32>]| {
            let mut out = vec![0.0; list.len() * dim];
            f.read(0, &mut out).unwrap();
            assert_eq!(out, list.concat());
            for (i, row) in list.iter().enumerate() {
                let mut one = vec![0.0; dim];
                f.read(i, &mut one).unwrap();
                assert_eq!(&one, row, "row {i}");
            }
        };
        check(&f, &list);
        // Appends go to the tail, writes to base rows become patches (the
        // same row twice reuses its slot), swap-removes cross the two.
        f.append(&[-1.0, -1.0, -1.0, -2.0, -2.0, -2.0]).unwrap();
        list.extend([vec![-1.0; 3], vec![-2.0; 3]]);
        f.write(2, &[9.0, 9.0, 9.0]).unwrap();
        f.write(2, &[8.0, 8.0, 8.0]).unwrap();
        list[2] = vec![8.0; 3];
        f.write(6, &[5.0, 5.0, 5.0, 6.0, 6.0, 6.0]).unwrap();
        list[6] = vec![5.0; 3];
        list[7] = vec![6.0; 3];
        assert_eq!(f.patch_slots, 2);
        check(&f, &list);
        for (remove, last) in [(1, 8), (0, 7), (3, 6), (5, 5)] {
            let mut row = vec![0.0; dim];
            f.read(last, &mut row).unwrap();
            if remove != last {
                f.write(remove, &row).unwrap();
            }
            f.truncate(last).unwrap();
            list.swap_remove(remove);
            check(&f, &list);
        }
        assert_eq!(f.len(), 5);
        f.truncate(2).unwrap();
        list.truncate(2);
        f.append(&[7.0, 7.0, 7.0]).unwrap();
        list.push(vec![7.0; 3]);
        check(&f, &list);
        assert_eq!(
            std::fs::read(&path).unwrap(),
            bytes,
            "the base is untouched"
        );
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
