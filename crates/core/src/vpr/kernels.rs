//! The inner loops of the descriptor scan, compiled for the CPU at hand.
//!
//! A query reads every stored descriptor, so the scan is bound by memory
//! bandwidth and, once descriptors are one-byte codes, by the multiply-adds
//! per byte. Two kinds of kernel live here:
//!
//! - **code dot products** (`u8` row codes against up to three `i8` query
//!   codes, exact `i32` sums): on x86-64 with AVX-512 VNNI one `vpdpbusd`
//!   does 64 multiply-adds, which keeps the scan at the memory floor; the
//!   compiler does not emit it from plain code, so that kernel is written
//!   with `core::arch` intrinsics. Everywhere else the plain loop is
//!   compiled per instruction set by [`multiversion`] (AVX2, NEON) and the
//!   best clone is chosen once at run time;
//! - **f32 dot products** for exact scoring, also through [`multiversion`].
//!   Clones only change the instruction set, never the order of the
//!   additions (Rust does not contract or reassociate floating point), so
//!   every clone returns bit-identical results.
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
    /// The portable loop, in its best [`multiversion`] clone.
    Portable,
}

impl CodeKernel {
    /// The fastest kernel this CPU runs.
    pub fn detect() -> CodeKernel {
        static KERNEL: OnceLock<CodeKernel> = OnceLock::new();
        *KERNEL.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512vnni")
            {
                return CodeKernel(Kind::Avx512Vnni);
            }
            CodeKernel(Kind::Portable)
        })
    }

    /// `Σ_i row[i] · q[i]` for each query and each of the consecutive rows
    /// of `stride` bytes in `rows`, into `out` (one entry per row), with
    /// rows as stored (`u8`) and queries as `i8` of `stride` bytes, a
    /// multiple of [`CODE_BLOCK`]. One call per block keeps the queries in
    /// registers and the loads streaming.
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
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512Vnni => vnni_dots_rows(rows, stride, queries, out),
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
    pub fn pays_off(self) -> bool {
        self.0 != Kind::Portable
    }

    /// The portable kernel, whatever the CPU (for tests and benchmarks).
    pub fn portable() -> CodeKernel {
        CodeKernel(Kind::Portable)
    }
}

/// Calls the VNNI kernel over a block of rows; only reachable through a
/// [`CodeKernel`] that [`CodeKernel::detect`] made.
#[cfg(target_arch = "x86_64")]
#[allow(
    unsafe_code,
    reason = "calling a #[target_feature] function needs unsafe; the features were detected at run time"
)]
fn vnni_dots_rows<const Q: usize>(
    rows: &[u8],
    stride: usize,
    queries: &[&[i8]; Q],
    out: &mut [[i32; Q]],
) {
    // SAFETY: `Kind::Avx512Vnni` is private to this module and only chosen
    // by `CodeKernel::detect` after `is_x86_feature_detected!` confirmed
    // avx512f, avx512bw and avx512vnni; the function has no other
    // precondition.
    unsafe { vnni::dots_rows(rows, stride, queries, out) }
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
        for blocks in [1, 2, 8, 20] {
            let n = blocks * CODE_BLOCK;
            let row: Vec<u8> = (0..n).map(|_| next() as u8).collect();
            let qs: Vec<Vec<i8>> = (0..3)
                .map(|_| (0..n).map(|_| next() as i8).collect())
                .collect();
            // Extremes: every product at its largest magnitude.
            let max_row = vec![255u8; n];
            let min_q = vec![-128i8; n];
            for kernel in [CodeKernel::detect(), CodeKernel::portable()] {
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
                let [extreme] = dots(kernel, &max_row, &[&min_q]);
                assert_eq!(extreme, -255 * 128 * n as i32);
            }
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
