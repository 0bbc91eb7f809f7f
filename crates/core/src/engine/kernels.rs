//! The inner loops of the descriptor scan, compiled for the CPU at hand.
//!
//! A query reads every stored descriptor, so the scan is bound by memory
//! bandwidth and, once descriptors are one-byte codes, by the multiply-adds
//! per byte. Two kinds of kernel live here:
//!
//! - **code dot products** (`u8` row codes against up to three `i8` query
//!   codes, exact `i32` sums): on x86-64 with AVX-512 VNNI one `vpdpbusd`
//!   does 64 multiply-adds, which keeps the scan at the memory floor; with
//!   AVX2 only, `vpmaddubsw` + `vpmaddwd` do 32 in two instructions, exact
//!   as long as query codes stay within ±64 (two products share a
//!   saturating `i16`), so queries are coded in that range for it. The
//!   compiler emits neither from plain code, so both are written with
//!   `core::arch` intrinsics. Everywhere else the plain loop is compiled
//!   per instruction set by [`multiversion`] (NEON, …). The best kernel is
//!   chosen once at run time;
//! - **f32 dot products** for exact scoring, also through [`multiversion`].
//!   Clones only change the instruction set, never the order of the
//!   additions (Rust does not contract or reassociate floating point), so
//!   every clone returns bit-identical results. The one SCAL runs for
//!   every row of an exact pass, eight lanes of sums against up to three
//!   queries ([`f32_lane_sums`]), is written with AVX intrinsics as well:
//!   LLVM vectorised the plain loop into pairs of lanes there (twice the
//!   time); `vmulps` then `vaddps` round each lane exactly as the plain
//!   loop does, so the sums are the same bits.
//!
//! Lengths must be multiples of [`CODE_BLOCK`] for the code kernels; the
//! code matrix pads rows and queries with zeros to get there.

use std::sync::OnceLock;

use multiversion::multiversion;

/// Code rows and queries are padded to a multiple of this many bytes.
pub const CODE_BLOCK: usize = 64;

/// The code dot-product kernel chosen for this CPU, detected once. Its
/// variant is private: only [`CodeKernel::detect`] can pick the VNNI kernel,
/// which is what makes calling it sound.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodeKernel(Kind);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// AVX-512 with VNNI (`vpdpbusd`).
    Avx512Vnni,
    /// AVX2 (`vpmaddubsw` + `vpmaddwd`), with query codes in [−64, 64].
    Avx2,
    /// The portable loop, in its best [`multiversion`] clone.
    Portable,
}

/// The variable that picks a slower kernel than the CPU's best, for
/// benchmarks and diagnosis: `avx2` or `portable` (a kernel the CPU lacks
/// is never chosen).
pub const KERNEL_VARIABLE: &str = "HUMEM_CODE_KERNEL";

impl CodeKernel {
    /// The fastest kernel this CPU runs (or the one [`KERNEL_VARIABLE`]
    /// names, if this CPU runs it), detected once.
    pub fn detect() -> CodeKernel {
        static KERNEL: OnceLock<CodeKernel> = OnceLock::new();
        *KERNEL.get_or_init(|| {
            let available = CodeKernel::available();
            let wanted = std::env::var(KERNEL_VARIABLE).ok();
            wanted
                .and_then(|name| available.iter().copied().find(|k| k.name() == name))
                .unwrap_or(available[0])
        })
    }

    /// Every kernel this CPU runs, fastest first (the portable one last).
    pub fn available() -> Vec<CodeKernel> {
        let mut kernels = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512vnni")
            {
                kernels.push(CodeKernel(Kind::Avx512Vnni));
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                kernels.push(CodeKernel(Kind::Avx2));
            }
        }
        kernels.push(CodeKernel(Kind::Portable));
        kernels
    }

    /// The kernel's name: `avx512vnni`, `avx2` or `portable`.
    pub fn name(self) -> &'static str {
        match self.0 {
            Kind::Avx512Vnni => "avx512vnni",
            Kind::Avx2 => "avx2",
            Kind::Portable => "portable",
        }
    }

    /// The largest query code magnitude the kernel multiplies exactly:
    /// `vpmaddubsw` adds two products in a saturating `i16`, and
    /// 2 · 255 · 64 = 32 640 still fits, so AVX2 takes query codes in
    /// [−64, 64]; the others take [−127, 127]. The error bound uses the
    /// query's own scale, so it holds either way; a coarser query code only
    /// widens it a little.
    pub fn query_levels(self) -> u8 {
        match self.0 {
            Kind::Avx2 => 64,
            _ => 127,
        }
    }

    /// `Σ_i row[i] · q[i]` for each query and each of the consecutive rows
    /// of `stride` bytes in `rows`, into `out` (one entry per row), with
    /// rows as stored (`u8`) and queries as `i8` of `stride` bytes, a
    /// multiple of [`CODE_BLOCK`], within ±[`CodeKernel::query_levels`].
    /// One call per block keeps the queries in registers and the loads
    /// streaming.
    pub fn dots_rows<const Q: usize>(
        self,
        rows: &[u8],
        stride: usize,
        queries: &[&[i8]; Q],
        out: &mut [[i32; Q]],
    ) {
        debug_assert_eq!(rows.len(), stride * out.len());
        debug_assert_eq!(stride % CODE_BLOCK, 0);
        debug_assert!(queries.iter().all(|q| q.len() == stride));
        debug_assert!(queries
            .iter()
            .all(|q| q.iter().all(|&c| c.unsigned_abs() <= self.query_levels())));
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            kind @ (Kind::Avx512Vnni | Kind::Avx2) => {
                vector_dots_rows(kind, rows, stride, queries, out)
            }
            _ => {
                for (row, o) in rows.chunks_exact(stride).zip(out) {
                    *o = queries.map(|q| portable_code_dot(row, q));
                }
            }
        }
    }

    /// Whether this kernel reads codes faster than the f32 scan reads
    /// descriptors. The portable loop is not: without a byte dot-product
    /// instruction the compiler multiplies in 32-bit lanes, and the code
    /// pass ends up slower than the f32 one (measured on this project's
    /// development machine: 220 ns per 512-byte row against 180 ns per
    /// 2 KB f32 row), so `vpr.scan = "auto"` keeps the exact pass there.
    /// Both vector kernels do (docs/benchmarks.md, "Scan at fleet scale", has the
    /// table: 0.45× the f32 scan on one core with VNNI, 0.69× with AVX2).
    pub fn pays_off(self) -> bool {
        self.0 != Kind::Portable
    }

    /// The portable kernel, whatever the CPU (for tests and benchmarks).
    pub fn portable() -> CodeKernel {
        CodeKernel(Kind::Portable)
    }
}

/// `sums[k][lane] = Σ_i q_k[8i + lane] · row[8i + lane]` over the first
/// `full` values (a multiple of 8, within every slice), each lane's
/// products added in order, one rounding per multiply and per add: the
/// eight partial sums of [`crate::engine::matrix::multi_dot`]. With AVX where
/// the CPU has it (detected once), the plain loop elsewhere; the same bits
/// either way.
pub fn f32_lane_sums<const Q: usize>(
    queries: &[&[f32]; Q],
    row: &[f32],
    full: usize,
) -> [[f32; 8]; Q] {
    debug_assert_eq!(full % 8, 0);
    #[cfg(target_arch = "x86_64")]
    if has_avx() {
        return avx_lane_sums(queries, row, full);
    }
    portable_lane_sums(queries, row, full)
}

/// Whether this CPU has AVX, detected once.
#[cfg(target_arch = "x86_64")]
fn has_avx() -> bool {
    static AVX: OnceLock<bool> = OnceLock::new();
    *AVX.get_or_init(|| std::arch::is_x86_feature_detected!("avx"))
}

/// [`f32_lane_sums`] through [`avx::lane_sums`], once AVX is detected.
#[cfg(target_arch = "x86_64")]
#[allow(
    unsafe_code,
    reason = "calling a #[target_feature] function needs unsafe; the feature was detected at run time"
)]
fn avx_lane_sums<const Q: usize>(queries: &[&[f32]; Q], row: &[f32], full: usize) -> [[f32; 8]; Q] {
    // SAFETY: only called after `has_avx()` confirmed AVX at run time;
    // the function has no other precondition.
    unsafe { avx::lane_sums(queries, row, full) }
}

/// [`f32_lane_sums`] as a plain loop, one query at a time.
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2+fma", "aarch64+neon"))]
fn portable_lane_sums<const Q: usize>(
    queries: &[&[f32]; Q],
    row: &[f32],
    full: usize,
) -> [[f32; 8]; Q] {
    let mut acc = [[0.0f32; 8]; Q];
    for (sums, q) in acc.iter_mut().zip(queries) {
        let mut local = [0.0f32; 8];
        for (r, q) in row[..full].chunks_exact(8).zip(q[..full].chunks_exact(8)) {
            for lane in 0..8 {
                local[lane] += q[lane] * r[lane];
            }
        }
        *sums = local;
    }
    acc
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use core::arch::x86_64::{__m256, _mm256_add_ps, _mm256_mul_ps, _mm256_setzero_ps};

    /// Eight values as one vector register (a safe bit cast).
    #[inline(always)]
    fn lanes(block: &[f32]) -> __m256 {
        let array: [f32; 8] = block.try_into().expect("8 lanes");
        bytemuck::cast(array)
    }

    /// [`super::f32_lane_sums`]: each row block is loaded once and
    /// multiplied by every query's block (`vmulps`, then `vaddps` into
    /// that query's sums).
    #[target_feature(enable = "avx")]
    pub fn lane_sums<const Q: usize>(
        queries: &[&[f32]; Q],
        row: &[f32],
        full: usize,
    ) -> [[f32; 8]; Q] {
        let mut acc = [_mm256_setzero_ps(); Q];
        for (i, r) in row[..full].chunks_exact(8).enumerate() {
            let r = lanes(r);
            for (a, q) in acc.iter_mut().zip(queries) {
                *a = _mm256_add_ps(*a, _mm256_mul_ps(lanes(&q[i * 8..i * 8 + 8]), r));
            }
        }
        acc.map(bytemuck::cast)
    }
}

/// Calls a vector kernel over a block of rows; only reachable through a
/// [`CodeKernel`] that [`CodeKernel::available`] made, which is what makes
/// each call sound.
#[cfg(target_arch = "x86_64")]
#[allow(
    unsafe_code,
    reason = "calling a #[target_feature] function needs unsafe; the features were detected at run time"
)]
fn vector_dots_rows<const Q: usize>(
    kind: Kind,
    rows: &[u8],
    stride: usize,
    queries: &[&[i8]; Q],
    out: &mut [[i32; Q]],
) {
    match kind {
        // SAFETY: `Kind::Avx512Vnni` is private to this module and only
        // made by `CodeKernel::available` after `is_x86_feature_detected!`
        // confirmed avx512f, avx512bw and avx512vnni; the function has no
        // other precondition.
        Kind::Avx512Vnni => unsafe { vnni::dots_rows(rows, stride, queries, out) },
        // SAFETY: `Kind::Avx2` is only made by `CodeKernel::available`
        // after `is_x86_feature_detected!("avx2")`; the function has no
        // other precondition (the query range only affects the result's
        // exactness, which `dots_rows` documents).
        Kind::Avx2 => unsafe { avx2::dots_rows(rows, stride, queries, out) },
        Kind::Portable => unreachable!("the portable kernel is not a vector kernel"),
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::{
        __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_extracti128_si256,
        _mm256_madd_epi16, _mm256_maddubs_epi16, _mm256_set1_epi16, _mm256_setzero_si256,
        _mm_add_epi32, _mm_cvtsi128_si32, _mm_hadd_epi32,
    };

    /// 32 bytes as one vector register (a safe bit cast).
    #[inline(always)]
    fn lanes<T: bytemuck::Pod>(block: &[T]) -> __m256i {
        let bytes: &[u8] = bytemuck::cast_slice(block);
        let array: [u8; 32] = bytes.try_into().expect("32-byte halves");
        bytemuck::cast(array)
    }

    /// [`dots`] for each row of a block.
    #[target_feature(enable = "avx2")]
    pub fn dots_rows<const Q: usize>(
        rows: &[u8],
        stride: usize,
        queries: &[&[i8]; Q],
        out: &mut [[i32; Q]],
    ) {
        for (row, o) in rows.chunks_exact(stride).zip(out) {
            *o = dots(row, queries);
        }
    }

    /// `vpmaddubsw` multiplies 32 unsigned row bytes by 32 signed query
    /// bytes and adds neighbouring pairs into 16 `i16` lanes (no
    /// saturation with query codes within ±64); `vpmaddwd` by ones widens
    /// and adds pairs again into 8 `i32` lanes.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn dots<const Q: usize>(row: &[u8], queries: &[&[i8]; Q]) -> [i32; Q] {
        let ones = _mm256_set1_epi16(1);
        let mut acc = [_mm256_setzero_si256(); Q];
        for (half, r) in row.chunks_exact(32).enumerate() {
            let r = lanes(r);
            let start = half * 32;
            for (a, q) in acc.iter_mut().zip(queries) {
                let pairs = _mm256_maddubs_epi16(r, lanes(&q[start..start + 32]));
                *a = _mm256_add_epi32(*a, _mm256_madd_epi16(pairs, ones));
            }
        }
        let mut sums = [0i32; Q];
        for (s, a) in sums.iter_mut().zip(acc) {
            let x = _mm_add_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256::<1>(a));
            let x = _mm_hadd_epi32(x, x);
            let x = _mm_hadd_epi32(x, x);
            *s = _mm_cvtsi128_si32(x);
        }
        sums
    }
}

#[cfg(target_arch = "x86_64")]
mod vnni {
    use core::arch::x86_64::{
        __m512i, _mm512_dpbusd_epi32, _mm512_reduce_add_epi32, _mm512_setzero_si512,
    };

    /// 64 row bytes as one vector register (a safe bit cast).
    #[inline(always)]
    fn row_lanes(block: &[u8]) -> __m512i {
        let array: [u8; 64] = block.try_into().expect("64-byte blocks");
        bytemuck::cast(array)
    }

    /// 64 query bytes as one vector register.
    #[inline(always)]
    fn query_lanes(block: &[i8]) -> __m512i {
        let array: [i8; 64] = block.try_into().expect("64-byte blocks");
        bytemuck::cast(array)
    }

    /// [`dots`] for each row of a block.
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    pub fn dots_rows<const Q: usize>(
        rows: &[u8],
        stride: usize,
        queries: &[&[i8]; Q],
        out: &mut [[i32; Q]],
    ) {
        for (row, o) in rows.chunks_exact(stride).zip(out) {
            *o = dots(row, queries);
        }
    }

    /// `vpdpbusd` over 64-byte blocks: each instruction multiplies 64
    /// unsigned row bytes by 64 signed query bytes and adds the products
    /// into 16 `i32` lanes, four at a time, without saturation.
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    #[inline]
    fn dots<const Q: usize>(row: &[u8], queries: &[&[i8]; Q]) -> [i32; Q] {
        let mut acc = [_mm512_setzero_si512(); Q];
        for (block, r) in row.chunks_exact(super::CODE_BLOCK).enumerate() {
            let r = row_lanes(r);
            let start = block * super::CODE_BLOCK;
            for (a, q) in acc.iter_mut().zip(queries) {
                *a = _mm512_dpbusd_epi32(*a, r, query_lanes(&q[start..start + super::CODE_BLOCK]));
            }
        }
        let mut sums = [0i32; Q];
        for (s, a) in sums.iter_mut().zip(acc) {
            *s = _mm512_reduce_add_epi32(a);
        }
        sums
    }
}

#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2+fma", "aarch64+neon"))]
fn portable_code_dot(row: &[u8], q: &[i8]) -> i32 {
    row.iter()
        .zip(q)
        .map(|(&r, &q)| i32::from(r) * i32::from(q))
        .sum()
}

/// The f32 dot product with 16 independent partial sums, for scans where
/// only speed matters (the exact baseline a benchmark compares against).
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2+fma", "aarch64+neon"))]
pub fn dot_f32_wide(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let mut acc = [0.0f32; 16];
    let (a_blocks, b_blocks) = (a[..n].chunks_exact(16), b[..n].chunks_exact(16));
    let tail: f32 = a_blocks
        .remainder()
        .iter()
        .zip(b_blocks.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a_blocks.zip(b_blocks) {
        for lane in 0..16 {
            acc[lane] += x[lane] * y[lane];
        }
    }
    acc.iter().sum::<f32>() + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_lane_sums_are_the_plain_loops_bits() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        for dim in [8, 16, 512, 1280] {
            let row: Vec<f32> = (0..dim).map(|_| next() * 1e3).collect();
            let q: Vec<Vec<f32>> = (0..3).map(|_| (0..dim).map(|_| next()).collect()).collect();
            let queries = [&q[0][..], &q[1][..], &q[2][..]];
            let bits = |sums: [[f32; 8]; 3]| sums.map(|s| s.map(f32::to_bits));
            assert_eq!(
                bits(f32_lane_sums(&queries, &row, dim)),
                bits(portable_lane_sums(&queries, &row, dim)),
                "dim {dim}"
            );
        }
    }

    /// The kernel on one row.
    fn dots<const Q: usize>(kernel: CodeKernel, row: &[u8], queries: &[&[i8]; Q]) -> [i32; Q] {
        let mut out = [[0; Q]];
        kernel.dots_rows(row, row.len(), queries, &mut out);
        out[0]
    }

    fn reference(row: &[u8], q: &[i8]) -> i32 {
        row.iter().zip(q).map(|(&r, &q)| r as i32 * q as i32).sum()
    }

    #[test]
    fn every_kernel_matches_the_plain_sum() {
        let mut seed = 0x1234_5678_u32;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        let kernels = CodeKernel::available();
        assert!(kernels.contains(&CodeKernel::detect()));
        assert_eq!(*kernels.last().unwrap(), CodeKernel::portable());
        for kernel in kernels {
            let levels = i32::from(kernel.query_levels());
            for blocks in [1, 2, 8, 20] {
                let n = blocks * CODE_BLOCK;
                let mut code = || (next() as i32).rem_euclid(2 * levels + 1) - levels;
                let row: Vec<u8> = (0..n).map(|_| code() as u8 ^ 0x80).collect();
                let qs: Vec<Vec<i8>> = (0..3)
                    .map(|_| (0..n).map(|_| code() as i8).collect())
                    .collect();
                // Extremes: every product at its largest magnitude.
                let max_row = vec![255u8; n];
                let min_q = vec![-(levels as i8); n];
                let max_q = vec![levels as i8; n];
                let got = dots(kernel, &row, &[&qs[0], &qs[1], &qs[2]]);
                for (g, q) in got.iter().zip(&qs) {
                    assert_eq!(*g, reference(&row, q), "{kernel:?}, {n} bytes");
                }
                let [one] = dots(kernel, &row, &[&qs[1]]);
                assert_eq!(one, reference(&row, &qs[1]));
                let mut block = vec![[0i32; 3]; 2];
                let two_rows: Vec<u8> = row.iter().chain(&max_row).copied().collect();
                kernel.dots_rows(&two_rows, n, &[&qs[0], &qs[1], &qs[2]], &mut block);
                assert_eq!(block[0], got);
                assert_eq!(block[1], [0, 1, 2].map(|i| reference(&max_row, &qs[i])));
                let [low, high] = dots(kernel, &max_row, &[&min_q, &max_q]);
                assert_eq!(low, -255 * levels * n as i32, "{kernel:?}");
                assert_eq!(high, 255 * levels * n as i32, "{kernel:?}");
            }
        }
    }

    #[test]
    fn a_kernel_is_named_by_the_variable_only_if_this_cpu_runs_it() {
        let names: Vec<&str> = CodeKernel::available().iter().map(|k| k.name()).collect();
        assert!(names.contains(&"portable"));
        if std::env::var(KERNEL_VARIABLE).is_err() {
            assert_eq!(CodeKernel::detect().name(), names[0]);
        }
    }

    #[test]
    fn wide_f32_dot_is_a_dot_product() {
        for n in [0usize, 5, 16, 17, 512, 1283] {
            let a: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
            let b: Vec<f32> = (0..n).map(|i| (i as f32 * 0.11).cos()).collect();
            let naive: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            assert!(
                (dot_f32_wide(&a, &b) as f64 - naive).abs() < 1e-3,
                "n = {n}"
            );
        }
    }
}
