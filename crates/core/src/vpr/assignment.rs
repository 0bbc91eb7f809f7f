//! Maximum-weight one-to-one assignment on an `f32` matrix.
//!
//! `pathfinding::kuhn_munkres` solves the assignment exactly but needs an
//! integer (`Ord`) weight type and at most as many rows as columns. This
//! adapter hides both: weights in [0, 1] are scaled by 1e6 to `i64` (far
//! below any overflow for the handful of objects per class), the matrix is
//! transposed when it is taller than wide, and the caller sums the chosen
//! pairs from its own `f32` values, so the rounding only ever affects the
//! choice between near-equal assignments, never the reported score.

use pathfinding::prelude::{kuhn_munkres, Matrix};

/// Integer resolution of the weights handed to the solver.
const SCALE: f32 = 1e6;

fn scaled(w: f32) -> i64 {
    // `as` saturates and maps NaN to 0, so the solver never sees a
    // non-finite value.
    (w * SCALE).round() as i64
}

/// Pairs `(row, column)` of a maximum-weight one-to-one assignment of the
/// `rows × cols` row-major `weights`; `min(rows, cols)` pairs, empty when
/// either side is empty.
pub(crate) fn max_weight_assignment(
    rows: usize,
    cols: usize,
    weights: &[f32],
) -> Vec<(usize, usize)> {
    debug_assert_eq!(weights.len(), rows * cols);
    if rows == 0 || cols == 0 || weights.len() != rows * cols {
        return Vec::new();
    }
    if rows <= cols {
        let m = Matrix::from_fn(rows, cols, |(i, j)| scaled(weights[i * cols + j]));
        let (_, to_col) = kuhn_munkres(&m);
        to_col.into_iter().enumerate().collect()
    } else {
        let m = Matrix::from_fn(cols, rows, |(j, i)| scaled(weights[i * cols + j]));
        let (_, to_row) = kuhn_munkres(&m);
        let mut pairs: Vec<(usize, usize)> = to_row
            .into_iter()
            .enumerate()
            .map(|(j, i)| (i, j))
            .collect();
        pairs.sort_unstable();
        pairs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn total(cols: usize, w: &[f32], pairs: &[(usize, usize)]) -> f32 {
        pairs.iter().map(|&(i, j)| w[i * cols + j]).sum()
    }

    #[test]
    fn beats_greedy() {
        // Greedy takes 0.9 first, then is left with 0.1: 1.0.
        // Optimal: 0.8 + 0.7 = 1.5.
        let w = [0.9, 0.8, 0.7, 0.1];
        let pairs = max_weight_assignment(2, 2, &w);
        assert_eq!(pairs, vec![(0, 1), (1, 0)]);
        assert!((total(2, &w, &pairs) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn tall_matrices_are_transposed() {
        // 3 rows, 2 columns: rows 1 and 2 win (0.9 + 0.8 = 1.7 > any pair with row 0).
        let w = [0.1, 0.2, 0.9, 0.3, 0.4, 0.8];
        let pairs = max_weight_assignment(3, 2, &w);
        assert_eq!(pairs, vec![(1, 0), (2, 1)]);
        assert!((total(2, &w, &pairs) - 1.7).abs() < 1e-6);
    }

    #[test]
    fn empty_sides() {
        assert!(max_weight_assignment(0, 3, &[]).is_empty());
        assert!(max_weight_assignment(2, 0, &[]).is_empty());
    }
}
