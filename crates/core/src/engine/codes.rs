//! One-byte codes of the stored descriptors, with a bound on their error.
//!
//! A large store's scan reads every descriptor; at four bytes a value it is
//! bound by memory bandwidth. The codes are a quarter of that: each row is
//! scaled by its largest magnitude to integers in `[−127, 127]` (stored
//! offset by 128 as `u8`, the operand type of the fastest kernel in
//! [`kernels`](super::kernels)), and each query the same way as `i8`.
//!
//! The code dot product is only an estimate, but its error is bounded, per
//! row, without any assumption about the data: with `x̂`, `q̂` the decoded
//! codes, `e_x = ‖x − x̂‖`, `e_q = ‖q − q̂‖`,
//!
//! `|q·x − q̂·x̂| = |q̂·(x − x̂) + (q − q̂)·x| ≤ ‖q̂‖ e_x + e_q ‖x‖`
//!
//! (Cauchy–Schwarz), plus a margin for f32 rounding. The scan uses the
//! bound to decide which rows must be scored exactly, so the compressed
//! scan returns exactly what the f32 scan returns.

use super::kernels::{CodeKernel, CODE_BLOCK};

/// Codes of every row of a descriptor matrix, row-aligned with it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CodeMatrix {
    /// Descriptor length rounded up to [`CODE_BLOCK`].
    stride: usize,
    /// `stride` bytes per row: `code + 128`, zero-padded (128).
    codes: Vec<u8>,
    /// Per row: scale, residual norm `e_x`, norm `‖x‖` (the latter two
    /// rounded up).
    rows: Vec<RowCode>,
}

/// Some rows' codes, copied out of a [`CodeMatrix`]
/// ([`CodeMatrix::gathered`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CodeRows {
    codes: Vec<u8>,
    rows: Vec<RowCode>,
}

/// How one row's codes decode, and how far they are from the row.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct RowCode {
    scale: f32,
    residual: f32,
    norm: f32,
}

/// Integer codes of `values`: the scale, the codes in `[−levels, levels]`
/// (`levels` ≤ 127), the
/// residual norm `‖x − scale · code‖` and `‖x‖`, both rounded up. A row with
/// a non-finite value gets an infinite residual (its bound is then
/// infinite and it is always scored exactly).
fn quantize(values: &[f32], levels: u8, mut put: impl FnMut(usize, i8)) -> RowCode {
    let max = values.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let finite = values.iter().all(|v| v.is_finite());
    let top = f32::from(levels.min(127));
    let scale = if finite && max > 0.0 { max / top } else { 0.0 };
    // Four partial sums each, so that the additions do not wait on one
    // another (this runs for every row loaded at start).
    let (mut residual, mut norm) = ([0.0f64; 4], [0.0f64; 4]);
    let inverse = if scale > 0.0 { 1.0 / scale } else { 0.0 };
    for (i, &v) in values.iter().enumerate() {
        // Round half away from zero; `as` truncates and saturates (a plain
        // `round` is a libm call on baseline x86-64).
        let scaled = v * inverse;
        let c = (scaled + 0.5f32.copysign(scaled)).clamp(-top, top) as i8;
        put(i, c);
        let error = f64::from(v) - f64::from(scale) * f64::from(c);
        residual[i % 4] += error * error;
        norm[i % 4] += f64::from(v) * f64::from(v);
    }
    let (residual, norm) = (residual.iter().sum::<f64>(), norm.iter().sum::<f64>());
    let up = |x: f64| (x.sqrt() * (1.0 + 1e-6)) as f32;
    RowCode {
        scale,
        residual: if finite { up(residual) } else { f32::INFINITY },
        norm: if finite { up(norm) } else { f32::INFINITY },
    }
}

impl CodeMatrix {
    /// Codes for rows of `dim` values.
    pub fn new(dim: usize) -> CodeMatrix {
        CodeMatrix {
            stride: dim.div_ceil(CODE_BLOCK) * CODE_BLOCK,
            codes: Vec::new(),
            rows: Vec::new(),
        }
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The codes of `data`, rows of `dim` values, encoded on every core:
    /// for loading a whole matrix at once.
    pub fn from_rows(dim: usize, data: &[f32]) -> CodeMatrix {
        let mut matrix = CodeMatrix::new(dim);
        if dim > 0 {
            matrix.extend(dim, data);
        }
        matrix
    }

    /// Appends the codes of `data`, rows of `dim` values (this matrix's
    /// dimension), encoded on every core: for loading many rows at once.
    pub fn extend(&mut self, dim: usize, data: &[f32]) {
        use rayon::prelude::*;
        assert_eq!(
            dim.div_ceil(CODE_BLOCK) * CODE_BLOCK,
            self.stride,
            "rows of another dimension"
        );
        let start = self.codes.len();
        self.codes
            .resize(start + data.len() / dim * self.stride, 128);
        let codes = self.codes[start..]
            .par_chunks_exact_mut(self.stride)
            .zip(data.par_chunks_exact(dim))
            .map(|(codes, row)| quantize(row, 127, |i, c| codes[i] = (i16::from(c) + 128) as u8));
        let mut rows = Vec::new();
        rows.par_extend(codes);
        self.rows.append(&mut rows);
    }

    /// Appends the codes of `row`.
    pub fn push(&mut self, row: &[f32]) {
        let start = self.codes.len();
        self.codes.resize(start + self.stride, 128);
        let code = self.encode_into(row, start);
        self.rows.push(code);
    }

    /// Replaces the codes of row `i`.
    pub fn set_row(&mut self, i: usize, row: &[f32]) {
        let start = i * self.stride;
        self.codes[start..start + self.stride].fill(128);
        self.rows[i] = self.encode_into(row, start);
    }

    fn encode_into(&mut self, row: &[f32], start: usize) -> RowCode {
        let stored = &mut self.codes[start..start + row.len()];
        quantize(row, 127, |i, c| stored[i] = (i16::from(c) + 128) as u8)
    }

    /// Moves the last row into row `i` and drops the last.
    pub fn swap_remove(&mut self, i: usize) {
        let last = self.rows.len() - 1;
        if i != last {
            self.codes
                .copy_within(last * self.stride.., i * self.stride);
        }
        self.codes.truncate(last * self.stride);
        self.rows.swap_remove(i);
    }

    /// Copies of the rows `order` lists, in that order: the first half of
    /// a reordering that reads under a shared lock
    /// ([`CodeMatrix::overwrite_rows`] is the other). The codes are copied
    /// as they are, not encoded again.
    pub fn gathered(&self, order: &[usize]) -> CodeRows {
        CodeRows {
            codes: crate::numeric::gather_rows(&self.codes, self.stride, order),
            rows: order.iter().map(|&row| self.rows[row]).collect(),
        }
    }

    /// Replaces the rows from `from` on with `rows` (as many as there
    /// are).
    pub fn overwrite_rows(&mut self, from: usize, rows: CodeRows) {
        let to = from + rows.rows.len();
        assert!(to <= self.len(), "rows past the end");
        self.codes[from * self.stride..to * self.stride].copy_from_slice(&rows.codes);
        self.rows[from..to].copy_from_slice(&rows.rows);
    }

    /// Removes every row.
    pub fn clear(&mut self) {
        self.codes.clear();
        self.rows.clear();
    }

    /// Code dot products of row `i` with the queries, as bounds on the
    /// exact f32 dot products: `(estimate, error bound)` per query, with
    /// `|q·x − estimate| ≤ bound` for `x` the f32 row.
    pub fn dot_bounds<const Q: usize>(
        &self,
        kernel: CodeKernel,
        i: usize,
        queries: &[&QueryCode; Q],
    ) -> [(f32, f32); Q] {
        let mut out = [[(0.0, 0.0); Q]];
        self.dot_bounds_rows(kernel, i, queries, &mut out);
        out[0]
    }

    /// [`CodeMatrix::dot_bounds`] of the rows from `first` on, one per
    /// entry of `out`, in one pass of the kernel.
    pub fn dot_bounds_rows<const Q: usize>(
        &self,
        kernel: CodeKernel,
        first: usize,
        queries: &[&QueryCode; Q],
        out: &mut [[(f32, f32); Q]],
    ) {
        self.for_each_sum(kernel, first, queries, out, |o, code, sums| {
            for ((o, q), &sum) in o.iter_mut().zip(queries).zip(sums) {
                *o = estimate_and_bound(q, code, sum);
            }
        });
    }

    /// Upper bounds `estimate + bound` on the products of the rows from
    /// `first` on with each query (as [`CodeMatrix::dot_bounds_rows`]
    /// gives them, added in the same way), one per entry of `out`. The scan
    /// needs only these, and without the pairs in between its pass stays in
    /// registers.
    pub fn upper_bounds_rows<const Q: usize>(
        &self,
        kernel: CodeKernel,
        first: usize,
        queries: &[&QueryCode; Q],
        out: &mut [[f32; Q]],
    ) {
        self.for_each_sum(kernel, first, queries, out, |o, code, sums| {
            for ((o, q), &sum) in o.iter_mut().zip(queries).zip(sums) {
                let (estimate, bound) = estimate_and_bound(q, code, sum);
                *o = estimate + bound;
            }
        });
    }

    /// The kernel's sums for the rows from `first` on, 64 rows at a time
    /// on the stack, handed to `each` with the row's entry of `out` and
    /// its [`RowCode`].
    #[inline(always)]
    fn for_each_sum<const Q: usize, T>(
        &self,
        kernel: CodeKernel,
        first: usize,
        queries: &[&QueryCode; Q],
        out: &mut [T],
        mut each: impl FnMut(&mut T, &RowCode, &[i32; Q]),
    ) {
        const GROUP: usize = 64;
        let mut sums = [[0i32; Q]; GROUP];
        let query_codes = queries.map(|q| q.codes.as_slice());
        for (g, out) in out.chunks_mut(GROUP).enumerate() {
            let start = first + g * GROUP;
            let rows = &self.codes[start * self.stride..(start + out.len()) * self.stride];
            let sums = &mut sums[..out.len()];
            kernel.dots_rows(rows, self.stride, &query_codes, sums);
            for ((o, sums), code) in out.iter_mut().zip(sums.iter()).zip(&self.rows[start..]) {
                each(o, code, sums);
            }
        }
    }
}

/// The estimate of a query's product with a row from their codes' sum,
/// and the bound on its error (infinite where it is not a number).
#[inline(always)]
fn estimate_and_bound(q: &QueryCode, code: &RowCode, sum: i32) -> (f32, f32) {
    // Exact in i64; f32 rounds it (and the scales' product) by a few parts
    // in 10⁸, which the bound's relative term covers.
    let exact = i64::from(sum) - 128 * q.sum;
    let estimate = exact as f32 * (q.scale * code.scale);
    let bound = q.decoded_norm * code.residual
        + (q.residual + q.rounding) * code.norm
        + estimate.abs() * 1e-6
        + ROUNDING_FLOOR;
    (estimate, if bound.is_nan() { f32::INFINITY } else { bound })
}

/// Added to every bound, with a millionth of the estimate: covers the
/// rounding of the estimate itself.
const ROUNDING_FLOOR: f32 = 1e-5;

/// One query descriptor's codes, prepared once per query.
#[derive(Debug, Clone, PartialEq)]
pub struct QueryCode {
    codes: Vec<i8>,
    /// `Σ codes`, to remove the rows' +128 offset.
    sum: i64,
    scale: f32,
    /// `e_q = ‖q − q̂‖`, rounded up.
    residual: f32,
    /// `‖q̂‖`, rounded up.
    decoded_norm: f32,
    /// Per unit of `‖x‖`: how far an f32 dot product of length `d` may be
    /// from the real one (`d · 2⁻²³ · ‖q‖`, generously).
    rounding: f32,
}

/// `values` scaled by their largest magnitude to integers in
/// `[−127, 127]`, as a row's codes are (without the offset): all zeros for
/// a zero or non-finite row.
pub fn i8_codes(values: &[f32]) -> Vec<i8> {
    let mut codes = vec![0i8; values.len()];
    let code = quantize(values, 127, |i, c| codes[i] = c);
    if !code.residual.is_finite() {
        codes.fill(0);
    }
    codes
}

impl QueryCode {
    /// Codes of `query` for a matrix of `codes`' row length, in the range
    /// `kernel` multiplies without overflow
    /// ([`CodeKernel::query_levels`]).
    pub fn new(query: &[f32], matrix: &CodeMatrix, kernel: CodeKernel) -> QueryCode {
        let mut codes = vec![0i8; matrix.stride];
        let n = query.len().min(matrix.stride);
        let code = quantize(&query[..n], kernel.query_levels(), |i, c| codes[i] = c);
        let decoded: f64 = codes
            .iter()
            .map(|&c| (f64::from(code.scale) * f64::from(c)).powi(2))
            .sum();
        QueryCode {
            sum: codes.iter().map(|&c| i64::from(c)).sum(),
            codes,
            scale: code.scale,
            residual: code.residual,
            decoded_norm: (decoded.sqrt() * (1.0 + 1e-6)) as f32,
            rounding: n as f32 * 1.2e-7 * code.norm,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::matrix::dot;
    use proptest::prelude::*;

    fn random_rows(seed: u64, n: usize, dim: usize) -> Vec<Vec<f32>> {
        let mut s = seed;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        (0..n)
            .map(|_| {
                let v: Vec<f32> = (0..dim).map(|_| next()).collect();
                let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                v.iter().map(|x| x / norm).collect()
            })
            .collect()
    }

    #[test]
    fn a_matrix_loaded_at_once_has_the_codes_of_one_built_row_by_row() {
        for dim in [3, 100, 512] {
            let rows = random_rows(dim as u64, 300, dim);
            let mut pushed = CodeMatrix::new(dim);
            rows.iter().for_each(|row| pushed.push(row));
            assert_eq!(CodeMatrix::from_rows(dim, &rows.concat()), pushed);
        }
    }

    #[test]
    fn the_bound_holds_and_is_tight_enough_to_be_useful() {
        for dim in [3, 64, 100, 512, 1280] {
            let rows = random_rows(dim as u64, 200, dim);
            let mut m = CodeMatrix::new(dim);
            for r in &rows {
                m.push(r);
            }
            let mut worst = 0.0f32;
            for kernel in CodeKernel::available() {
                let q = QueryCode::new(&rows[7], &m, kernel);
                for (i, r) in rows.iter().enumerate() {
                    let [(estimate, bound)] = m.dot_bounds(kernel, i, &[&q]);
                    let exact = dot(&rows[7], r);
                    assert!((exact - estimate).abs() <= bound, "dim {dim} row {i}");
                    worst = worst.max(bound);
                }
            }
            // Unit vectors: the bound is a few hundredths at most.
            assert!(worst < 0.05, "dim {dim}: bound {worst}");
        }
    }

    #[test]
    fn swap_remove_and_set_row_keep_rows_aligned() {
        let rows = random_rows(1, 5, 70);
        let mut m = CodeMatrix::new(70);
        for r in &rows {
            m.push(r);
        }
        m.swap_remove(1);
        m.set_row(0, &rows[2]);
        let q = QueryCode::new(&rows[2], &m, CodeKernel::detect());
        let kernel = CodeKernel::detect();
        let expected = [2, 4, 2, 3];
        assert_eq!(m.len(), 4);
        for (i, &source) in expected.iter().enumerate() {
            let [(estimate, bound)] = m.dot_bounds(kernel, i, &[&q]);
            assert!((dot(&rows[2], &rows[source]) - estimate).abs() <= bound);
        }
        m.clear();
        assert!(m.is_empty());
    }

    #[test]
    fn degenerate_rows_are_always_rescored() {
        let mut m = CodeMatrix::new(4);
        m.push(&[0.0; 4]);
        m.push(&[f32::NAN, 1.0, 0.0, 0.0]);
        let q = QueryCode::new(&[0.5, 0.5, 0.5, 0.5], &m, CodeKernel::detect());
        let kernel = CodeKernel::detect();
        let [(estimate, bound)] = m.dot_bounds(kernel, 0, &[&q]);
        assert_eq!(estimate, 0.0);
        assert!(bound < 1e-4);
        let [(_, bound)] = m.dot_bounds(kernel, 1, &[&q]);
        assert_eq!(bound, f32::INFINITY);
    }

    proptest! {
        #[test]
        fn bounds_hold_for_any_values(
            rows in prop::collection::vec(prop::collection::vec(-10.0f32..10.0, 9), 1..20),
            q in prop::collection::vec(-10.0f32..10.0, 9),
        ) {
            let mut m = CodeMatrix::new(9);
            for r in &rows {
                m.push(r);
            }
            for kernel in CodeKernel::available() {
                let code = QueryCode::new(&q, &m, kernel);
                for (i, r) in rows.iter().enumerate() {
                    let [(estimate, bound)] = m.dot_bounds(kernel, i, &[&code]);
                    prop_assert!((dot(&q, r) - estimate).abs() <= bound, "{kernel:?}");
                }
            }
        }
    }
}
