//! A fixed random rotation that shortens descriptors for the neighbour
//! graph.
//!
//! Inserting a row into the graph compares it with a few hundred stored
//! rows, so its cost grows with the descriptor's length: at 1280 values the
//! inserts of a fleet took half of a two-core server. The graph only
//! proposes candidates, which are scored exactly afterwards, so it can
//! work on a shorter vector: the first `k` coordinates of the descriptor
//! in a random orthonormal basis. A random rotation spreads every
//! direction of the descriptor evenly over the coordinates (the
//! Johnson–Lindenstrauss argument), so the dot products of the shortened
//! vectors are those of the originals plus a small noise, whatever the
//! descriptor model, and needs nothing learnt from the data.
//!
//! The basis is a pure function of the two lengths: the generator is
//! defined here (SplitMix64, Box–Muller, modified Gram–Schmidt in f64), so
//! every process, replica and later build derives the same one, and a
//! graph saved by one is read by another. Changing the generator would
//! make saved graphs propose the wrong rows: a test pins its output.

use super::matrix::dot;

/// Rows of a `k × dim` matrix with orthonormal rows, applied as `P x`.
#[derive(Debug, Clone)]
pub struct Projection {
    dim: usize,
    rows: Vec<f32>,
}

/// SplitMix64: a small, fixed generator (not a secret source).
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    fn unit(&mut self) -> f64 {
        ((self.next() >> 11) + 1) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller, one of the pair).
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.unit(), self.unit());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

impl Projection {
    /// The projection of `dim`-value descriptors onto `k ≤ dim`
    /// coordinates of the fixed random basis for `dim`.
    pub fn new(dim: usize, k: usize) -> Projection {
        assert!(k <= dim && k > 0, "projection of {dim} values onto {k}");
        let mut rng = SplitMix(0x4855_4d65_6d00_0000 ^ dim as u64);
        let mut basis: Vec<Vec<f64>> = Vec::with_capacity(k);
        while basis.len() < k {
            let mut v: Vec<f64> = (0..dim).map(|_| rng.normal()).collect();
            // Modified Gram–Schmidt, twice for f64 round-off.
            for _ in 0..2 {
                for b in &basis {
                    let along: f64 = v.iter().zip(b).map(|(x, y)| x * y).sum();
                    v.iter_mut().zip(b).for_each(|(x, y)| *x -= along * y);
                }
            }
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 1e-6 {
                v.iter_mut().for_each(|x| *x /= norm);
                basis.push(v);
            }
        }
        let rows = basis.into_iter().flatten().map(|x| x as f32).collect();
        Projection { dim, rows }
    }

    /// Length of the vectors it gives.
    pub fn output_dim(&self) -> usize {
        self.rows.len() / self.dim.max(1)
    }

    /// `P x`: the first `k` coordinates of `x` in the basis.
    pub fn apply(&self, x: &[f32]) -> Vec<f32> {
        debug_assert_eq!(x.len(), self.dim);
        self.rows
            .chunks_exact(self.dim)
            .map(|r| dot(r, x))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{place_descriptor, Rng};

    #[test]
    fn the_basis_is_orthonormal() {
        let p = Projection::new(96, 32);
        assert_eq!((p.dim, p.output_dim()), (96, 32));
        for i in 0..32 {
            for j in 0..32 {
                let d = dot(&p.rows[i * 96..(i + 1) * 96], &p.rows[j * 96..(j + 1) * 96]);
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((d - want).abs() < 1e-5, "{i} {j} {d}");
            }
        }
        // A full basis is a rotation: lengths are kept.
        let full = Projection::new(16, 16);
        let x: Vec<f32> = (0..16).map(|i| (i as f32 * 0.7).sin()).collect();
        let y = full.apply(&x);
        assert!((dot(&x, &x) - dot(&y, &y)).abs() < 1e-4);
    }

    /// Saved graphs hold shortened rows: the basis must never change.
    #[test]
    fn the_basis_is_the_same_in_every_build() {
        let p = Projection::new(1280, 256);
        let pinned = [
            p.rows[0],
            p.rows[1],
            p.rows[1279],
            p.rows[1280],
            p.rows[256 * 1280 - 1],
        ];
        // What the generator gave when graphs were first saved with it; a
        // libm may differ in the last bit, a new generator in every value.
        let expected = [
            -0.021_417_43,
            -0.004_609_413_4,
            -0.007_538_296_7,
            0.040_831_335,
            0.022_910_604,
        ];
        for (got, want) in pinned.iter().zip(expected) {
            assert!((got - want).abs() < 1e-6, "{pinned:?}");
        }
        assert_eq!(Projection::new(1280, 256).rows, p.rows);
    }

    #[test]
    fn shortened_places_keep_their_neighbours() {
        let mut noise = Rng::new(5);
        let rows: Vec<Vec<f32>> = (0..400)
            .map(|i| place_descriptor(1280, (i / 4) as u64, &mut noise))
            .collect();
        let p = Projection::new(1280, 128);
        let short: Vec<Vec<f32>> = rows.iter().map(|r| p.apply(r)).collect();
        let cos = |a: &[f32], b: &[f32]| dot(a, b) / (dot(a, a) * dot(b, b)).sqrt();
        for q in (0..400).step_by(37) {
            let best = (0..400)
                .filter(|&r| r != q)
                .max_by(|&a, &b| cos(&short[q], &short[a]).total_cmp(&cos(&short[q], &short[b])))
                .unwrap();
            assert_eq!(best / 4, q / 4, "query {q} found {best}");
        }
    }
}
