//! The appearance channel: a second, appearance-robust similarity beside
//! the CNN descriptor's cosine.
//!
//! An ImageNet CNN pooled into one vector loses what it never learned to
//! see: fog, night, blur and tiny images. A SeqSLAM-style thumbnail (the
//! image in grey at 64×48, each 8×8 patch normalised to zero mean and unit
//! variance) keeps the coarse layout of light and dark whatever the
//! exposure, and matches where the CNN does not (docs/evaluation.md, "Perception quality").
//! It enters SCAL as `s_e = (1 − w) clip(cos) + w clip(ρ)`, with `ρ` the
//! thumbnails' correlation and `w` = `vpr.appearance_weight`, only when both
//! sides have a thumbnail (otherwise `s_e` is the cosine alone, as a missing
//! scene model leaves `s̃_e` alone). `w` is 0 by default: the channel raises
//! R@1 but, fused into one score, it widens the null that calibration
//! measures against, and fewer queries pass the threshold (docs/evaluation.md,
//! "Perception quality"). Thumbnails are computed and stored regardless, so
//! a store can turn it on without re-inserting.
//!
//! Thumbnails are `i8` (the patch z-scores × [`SCALE`]), 3 KiB a keyframe
//! against the descriptor's 5 KiB, kept in their own contiguous matrix with
//! each row's norm, and compared with an integer dot product that LLVM
//! vectorises.

/// Thumbnail width, in pixels.
pub const WIDTH: usize = 64;
/// Thumbnail height, in pixels.
pub const HEIGHT: usize = 48;
/// Values in a thumbnail.
pub const LEN: usize = WIDTH * HEIGHT;
/// Side of the square patches normalised on their own.
pub const PATCH: usize = 8;
/// A patch z-score `z` is stored as `round(z × SCALE)`, clamped to ±127.
pub const SCALE: f32 = 32.0;

/// Row-major matrix of thumbnails, one row per keyframe, with each row's
/// L2 norm; a keyframe without a thumbnail has norm 0 and a zero row. A
/// store of precomputed features without thumbnails holds no rows at all
/// (`data` stays empty until the first thumbnail), not 3 KiB of zeros per
/// keyframe.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AppearanceMatrix {
    /// Empty, or `norms.len() × LEN` values.
    data: Vec<i8>,
    norms: Vec<f32>,
}

impl AppearanceMatrix {
    /// Number of rows (keyframes), with or without a thumbnail.
    pub fn len(&self) -> usize {
        self.norms.len()
    }

    /// Whether the matrix has no rows.
    pub fn is_empty(&self) -> bool {
        self.norms.is_empty()
    }

    /// Appends a row: `thumbnail` must be empty (none) or [`LEN`] long
    /// (callers validate). Returns its index.
    pub fn push(&mut self, thumbnail: &[i8]) -> usize {
        if thumbnail.len() == LEN {
            // The first thumbnail gives the earlier rows their zeros.
            self.data.resize(self.norms.len() * LEN, 0);
            self.data.extend_from_slice(thumbnail);
            self.norms.push(norm(thumbnail));
        } else {
            debug_assert!(
                thumbnail.is_empty(),
                "thumbnail of {} values",
                thumbnail.len()
            );
            if !self.data.is_empty() {
                self.data.resize(self.data.len() + LEN, 0);
            }
            self.norms.push(0.0);
        }
        self.norms.len() - 1
    }

    /// Row `i` with its norm, `None` when that keyframe has no thumbnail.
    pub fn row(&self, i: usize) -> Option<(&[i8], f32)> {
        let norm = self.norms[i];
        (norm > 0.0).then(|| (&self.data[i * LEN..(i + 1) * LEN], norm))
    }

    /// Removes row `i` by moving the last row into its place.
    pub fn swap_remove(&mut self, i: usize) {
        let last = self.norms.len() - 1;
        if !self.data.is_empty() {
            if i != last {
                let (head, tail) = self.data.split_at_mut(last * LEN);
                head[i * LEN..(i + 1) * LEN].copy_from_slice(tail);
            }
            self.data.truncate(last * LEN);
        }
        self.norms.swap_remove(i);
    }

    /// Copies of the rows `order` lists, in that order (see
    /// [`AppearanceMatrix::overwrite_rows`]).
    pub fn gathered(&self, order: &[usize]) -> AppearanceMatrix {
        AppearanceMatrix {
            data: if self.data.is_empty() {
                Vec::new()
            } else {
                crate::numeric::gather_rows(&self.data, LEN, order)
            },
            norms: order.iter().map(|&row| self.norms[row]).collect(),
        }
    }

    /// Replaces the rows from `from` on with those of `rows` (as many as
    /// there are; gathered from this matrix).
    pub fn overwrite_rows(&mut self, from: usize, rows: AppearanceMatrix) {
        let to = from + rows.len();
        assert!(to <= self.len(), "rows past the end");
        if !self.data.is_empty() {
            self.data[from * LEN..to * LEN].copy_from_slice(&rows.data);
        }
        self.norms[from..to].copy_from_slice(&rows.norms);
    }

    /// Removes every row.
    pub fn clear(&mut self) {
        self.data.clear();
        self.norms.clear();
    }
}

/// The L2 norm of a thumbnail.
pub fn norm(thumbnail: &[i8]) -> f32 {
    (idot(thumbnail, thumbnail) as f32).sqrt()
}

/// `Σ a_i b_i` in integers, with independent accumulators so that it
/// vectorises. `|a_i b_i| ≤ 127²` and a row has [`LEN`] values, far inside
/// `i32`.
pub fn idot(a: &[i8], b: &[i8]) -> i32 {
    let mut acc = [0i32; 16];
    let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..16 {
            acc[k] += i32::from(x[k]) * i32::from(y[k]);
        }
    }
    let tail: i32 = ra
        .iter()
        .zip(rb)
        .map(|(&x, &y)| i32::from(x) * i32::from(y))
        .sum();
    acc.iter().sum::<i32>() + tail
}

/// `ρ = clip(aᵀb / (|a| |b|), 0, 1)`, the thumbnails' correlation (each
/// patch has zero mean, so the cosine is a correlation).
pub fn similarity((a, a_norm): (&[i8], f32), (b, b_norm): (&[i8], f32)) -> f32 {
    if a_norm <= 0.0 || b_norm <= 0.0 {
        return 0.0;
    }
    crate::numeric::clip01(idot(a, b) as f32 / (a_norm * b_norm))
}

/// `s_e` of one pair: the clipped descriptor cosine, blended with the
/// thumbnails' similarity when both sides have one and `weight > 0`.
pub fn fused(dot: f32, appearance: Option<f32>, weight: f32) -> f32 {
    let cosine = crate::numeric::clip01(dot);
    match appearance {
        Some(rho) if weight > 0.0 => (1.0 - weight) * cosine + weight * rho,
        _ => cosine,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn thumb(f: impl Fn(usize) -> i8) -> Vec<i8> {
        (0..LEN).map(f).collect()
    }

    #[test]
    fn integer_dot_and_similarity() {
        let a = thumb(|i| if i % 2 == 0 { 10 } else { -10 });
        let b = thumb(|i| if i % 4 < 2 { 10 } else { -10 });
        assert_eq!(idot(&a, &a), 100 * LEN as i32);
        // Half the products are +100, half −100.
        assert_eq!(idot(&a, &b), 0);
        let na = norm(&a);
        assert!((similarity((&a, na), (&a, na)) - 1.0).abs() < 1e-6);
        let minus: Vec<i8> = a.iter().map(|v| -v).collect();
        assert_eq!(similarity((&a, na), (&minus, na)), 0.0);
        // 3 of 4 values agree: ρ = (3 − 1) / 4 = 0.5.
        let c = thumb(|i| if i % 4 == 3 { -a[i] } else { a[i] });
        assert!((similarity((&a, na), (&c, norm(&c))) - 0.5).abs() < 1e-6);
        // Odd lengths use the tail.
        assert_eq!(idot(&[1, 2, 3], &[4, 5, 6]), 32);
    }

    #[test]
    fn fusion_needs_both_thumbnails_and_a_weight() {
        assert!((fused(0.8, Some(0.2), 0.25) - (0.75 * 0.8 + 0.25 * 0.2)).abs() < 1e-6);
        assert_eq!(fused(0.8, None, 0.25), 0.8);
        assert_eq!(fused(0.8, Some(0.2), 0.0), 0.8);
        assert_eq!(fused(-0.3, Some(0.5), 0.5), 0.25);
    }

    #[test]
    fn rows_without_thumbnails_and_swap_remove() {
        let mut m = AppearanceMatrix::default();
        let a = thumb(|i| (i % 7) as i8 - 3);
        let b = thumb(|i| (i % 5) as i8 - 2);
        assert_eq!(m.push(&a), 0);
        assert_eq!(m.push(&[]), 1);
        assert_eq!(m.push(&b), 2);
        assert!(m.row(1).is_none());
        m.swap_remove(0);
        assert_eq!(m.len(), 2);
        assert_eq!(m.row(0).unwrap().0, b.as_slice());
        assert!(m.row(1).is_none());
        m.swap_remove(1);
        assert_eq!(m.row(0).unwrap().1, norm(&b));
        m.clear();
        assert!(m.is_empty());
    }

    #[test]
    fn rows_before_the_first_thumbnail_cost_nothing_until_it_comes() {
        let mut m = AppearanceMatrix::default();
        m.push(&[]);
        m.push(&[]);
        assert!(m.data.is_empty());
        m.swap_remove(0);
        let a = thumb(|i| (i % 3) as i8 - 1);
        assert_eq!(m.push(&a), 1);
        assert_eq!(m.data.len(), 2 * LEN);
        assert!(m.row(0).is_none());
        assert_eq!(m.row(1).unwrap().0, a.as_slice());
    }
}
