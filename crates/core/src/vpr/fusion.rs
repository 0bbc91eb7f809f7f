//! Tri-layer fusion: object and text evidence corroborate the scene score,
//! and evidence against it takes some of it away.
//!
//! Fusion is scene-primary: the corroboration `B` is bounded to [0, 1] and
//! only closes part of the gap between `S_s` and 1, `Λ = S_s + (1 − S_s) B`
//! (the paper). Evidence for can therefore raise a hypothesis in proportion
//! to the remaining doubt. The contradiction `C` ∈ [0, 1]
//! ([`super::contradiction`]) mirrors it: it removes the same share of the
//! scene score, `Λ = S_s (1 − C) + (1 − S_s) B`, so `Λ` stays in [0, 1],
//! `C = 0` gives the paper's formula and `C = 1` leaves only what the
//! corroboration alone supports.

use crate::numeric::clip01;
use crate::vpr::params::VprParams;

/// `B = clip(g_o S_o + g_t E_t S_t, 0, 1)`.
pub fn corroboration(s_o: f32, s_t: f32, e_t: f32, params: &VprParams) -> f32 {
    clip01(params.g_o * s_o + params.g_t * e_t * s_t)
}

/// `Λ = S_s + (1 − S_s) B` (inputs taken in [0, 1]).
pub fn fuse(s_s: f32, b: f32) -> f32 {
    let s = clip01(s_s);
    (s + (1.0 - s) * clip01(b)).min(1.0)
}

/// `Λ = S_s (1 − C) + (1 − S_s) B` (inputs taken in [0, 1]).
pub fn fuse_with_contradiction(s_s: f32, b: f32, c: f32) -> f32 {
    let s = clip01(s_s);
    (s * (1.0 - clip01(c)) + (1.0 - s) * clip01(b)).min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::testing::close;
    use proptest::prelude::*;

    #[test]
    fn corroboration_values() {
        let p = VprParams::default();
        // 0.15 · 0.8 + 0.25 · 0.6 · 0.5 = 0.12 + 0.075 = 0.195.
        assert!(close(corroboration(0.8, 0.5, 0.6, &p), 0.195));
        // No evidence: 0.
        assert_eq!(corroboration(0.0, 0.0, 0.0, &p), 0.0);
        // Large gains clip at 1: 2 · 1 + 3 · 1 · 1 = 5 → 1.
        let big = VprParams {
            g_o: 2.0,
            g_t: 3.0,
            ..VprParams::default()
        };
        assert_eq!(corroboration(1.0, 1.0, 1.0, &big), 1.0);
        // 2 · 0.2 + 3 · 0.5 · 0.4 = 0.4 + 0.6 = 1.0 → exactly 1.
        assert!(close(corroboration(0.2, 0.4, 0.5, &big), 1.0));
    }

    #[test]
    fn fused_values() {
        // 0.6 + 0.4 · 0.195 = 0.678.
        assert!(close(fuse(0.6, 0.195), 0.678));
        // B = 0 keeps S_s; B = 1 gives 1; S_s = 1 stays 1.
        assert_eq!(fuse(0.6, 0.0), 0.6);
        assert!(close(fuse(0.6, 1.0), 1.0));
        assert_eq!(fuse(1.0, 0.3), 1.0);
        // 0.65 + 0.35 · 0.15 = 0.7025 (a scene score below τ_s lifted above it).
        assert!(close(fuse(0.65, 0.15), 0.7025));
    }

    #[test]
    fn contradiction_values() {
        // 0.8 · (1 − 0.5) + 0.2 · 0.1 = 0.4 + 0.02 = 0.42.
        assert!(close(fuse_with_contradiction(0.8, 0.1, 0.5), 0.42));
        // C = 0 is the paper's fusion: 0.6 + 0.4 · 0.195 = 0.678.
        assert!(close(fuse_with_contradiction(0.6, 0.195, 0.0), 0.678));
        // C = 1 leaves (1 − S_s) B: 0.3 · 0.2 = 0.06.
        assert!(close(fuse_with_contradiction(0.7, 0.2, 1.0), 0.06));
        // No evidence either way keeps S_s.
        assert_eq!(fuse_with_contradiction(0.6, 0.0, 0.0), 0.6);
    }

    proptest! {
        #[test]
        fn contradiction_bounds_and_direction(
            s_s in 0.0f32..=1.0,
            b in 0.0f32..=1.0,
            c0 in 0.0f32..=1.0,
            c1 in 0.0f32..=1.0,
        ) {
            let (lo, hi) = if c0 <= c1 { (c0, c1) } else { (c1, c0) };
            let l = fuse_with_contradiction(s_s, b, hi);
            prop_assert!((0.0..=1.0).contains(&l));
            // More evidence against never raises Λ, and never exceeds the paper's Λ.
            prop_assert!(l <= fuse_with_contradiction(s_s, b, lo) + 1e-6);
            prop_assert!(l <= fuse(s_s, b) + 1e-6);
        }

        #[test]
        fn fused_score_bounds(
            s_s in 0.0f32..=1.0,
            s_o in 0.0f32..=1.0,
            s_t in 0.0f32..=1.0,
            e_t in 0.0f32..=1.0,
        ) {
            let b = corroboration(s_o, s_t, e_t, &VprParams::default());
            prop_assert!((0.0..=1.0).contains(&b));
            let l = fuse(s_s, b);
            prop_assert!((0.0..=1.0).contains(&l));
            prop_assert!(l >= s_s);
        }

        #[test]
        fn fused_score_monotone_in_b(s_s in 0.0f32..=1.0, b0 in 0.0f32..=1.0, b1 in 0.0f32..=1.0) {
            let (lo, hi) = if b0 <= b1 { (b0, b1) } else { (b1, b0) };
            prop_assert!(fuse(s_s, hi) >= fuse(s_s, lo));
        }

        #[test]
        fn corroboration_clipped_for_any_gains(
            s_o in 0.0f32..=1.0,
            s_t in 0.0f32..=1.0,
            e_t in 0.0f32..=1.0,
            g_o in 0.0f32..10.0,
            g_t in 0.0f32..10.0,
        ) {
            let p = VprParams { g_o, g_t, ..VprParams::default() };
            prop_assert!((0.0..=1.0).contains(&corroboration(s_o, s_t, e_t, &p)));
        }
    }
}
