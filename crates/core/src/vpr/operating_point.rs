//! An operating point that holds: the selection threshold each store
//! adapts from SLAM's verdicts, so that the candidates it sends to
//! geometric verification keep a configured precision on ground the
//! default threshold was never tuned on.
//!
//! Every loop or merge verdict that carries the score HuMem gave its
//! candidate ([`crate::verdict::Verdict::score`]) is one labelled sample of
//! "what a candidate scored, and whether it was a true place"
//! (relocalisations are left out: a lost frame's failed PnP says more about
//! the frame than the candidate, see [`super::feedback`]). Geometry is not a
//! perfect label: it also rejects true places (too few matches under
//! appearance change), with a probability `m`, the configured
//! `geometry_miss_rate`. So for a candidate threshold `τ`, with `w_i` each
//! verdict's decayed weight ([`super::feedback::VerdictParams::weight`]) and
//! `s_i` its score:
//!
//! - `n(τ) = Σ w_i [s_i > τ]`, the candidates that would still be sent;
//! - `a(τ) = Σ w_i [s_i > τ, accepted_i]`, those geometry accepted;
//! - `T̂(τ) = min(n, a / (1 − m))`, the true places among them (each true
//!   place is accepted with probability `1 − m`);
//! - `p̂(τ) = T̂ / n`, the estimated candidate precision.
//!
//! The adapted threshold is the smallest `τ` on the grid `τ_0 + k · 0.01`
//! (`τ_0` the configured threshold, `k = 0 … K`, `K · 0.01 =
//! max_threshold_raise`) at which `p̂(τ) ≥ target_precision` or nothing is
//! left to judge (`n = 0`); where no grid point qualifies, the top of the
//! grid. It never goes below `τ_0`: below it no candidate was ever sent,
//! so no verdict can say what lies there. Until `min_verdicts` scored
//! verdicts above `τ_0` exist, it is `τ_0`. The estimate is over the whole
//! store (one operating point per store, as one threshold per server
//! today); a query that names its own threshold keeps it.
//!
//! Shaped as a pure function of `(score, accepted, weight)` samples, so
//! that the rule is pinned by hand-computed tests and the index only has
//! to cache its result ([`crate::index::Index::operating_point`]).

use serde::Serialize;

/// Step of the threshold grid.
pub const GRID_STEP: f32 = 0.01;

/// One verdict as the estimate sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The score HuMem gave the candidate.
    pub score: f32,
    /// Whether geometry accepted it.
    pub accepted: bool,
    /// Its decayed weight `w`.
    pub weight: f64,
}

/// The settings of the rule (from `[vpr.verdicts]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rule {
    /// `τ_0`, the configured threshold.
    pub base: f32,
    /// The precision to hold, in (0, 1].
    pub target_precision: f64,
    /// `m`, the share of true places geometry rejects, in [0, 1).
    pub geometry_miss_rate: f64,
    /// Scored verdicts above `τ_0` needed before the threshold adapts.
    pub min_verdicts: usize,
    /// `K · 0.01`, the most the threshold rises above `τ_0`.
    pub max_raise: f32,
}

/// The store's operating point now.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct OperatingPoint {
    /// The threshold a query that names none gets.
    pub threshold: f32,
    /// `p̂` at that threshold (None while too few verdicts exist, or where
    /// nothing above it was judged).
    pub estimated_precision: Option<f64>,
    /// `p̂` at `τ_0`, what the configured threshold would give (None while
    /// too few verdicts exist).
    pub base_precision: Option<f64>,
    /// Scored verdicts above `τ_0`.
    pub verdicts: usize,
}

impl OperatingPoint {
    /// The configured threshold, unadapted.
    pub fn fixed(base: f32) -> OperatingPoint {
        OperatingPoint {
            threshold: base,
            estimated_precision: None,
            base_precision: None,
            verdicts: 0,
        }
    }
}

/// `p̂` from `n` and `a` (None when `n = 0`).
fn precision_of(n: f64, a: f64, miss_rate: f64) -> Option<f64> {
    (n > 0.0).then(|| (a / (1.0 - miss_rate)).min(n) / n)
}

/// `p̂` of the samples scored above `tau` (None when `n = 0`).
#[cfg(test)]
fn estimated_precision(samples: &[Sample], tau: f32, miss_rate: f64) -> Option<f64> {
    let (mut n, mut a) = (0.0f64, 0.0f64);
    for s in samples.iter().filter(|s| s.score > tau) {
        n += s.weight;
        if s.accepted {
            a += s.weight;
        }
    }
    precision_of(n, a, miss_rate)
}

/// The rule of the module doc over `samples`, in one pass over them: each
/// sample adds its weight to the grid points strictly below its score
/// (found by binary search over the grid), summed from the top down.
pub fn adapt(rule: &Rule, samples: &[Sample]) -> OperatingPoint {
    let above = samples.iter().filter(|s| s.score > rule.base).count();
    if above < rule.min_verdicts.max(1) {
        return OperatingPoint {
            verdicts: above,
            ..OperatingPoint::fixed(rule.base)
        };
    }
    let m = rule.geometry_miss_rate;
    let steps = (rule.max_raise / GRID_STEP).round() as usize;
    let grid: Vec<f32> = (0..=steps)
        .map(|k| rule.base + k as f32 * GRID_STEP)
        .collect();
    // `n[k]`, `a[k]`: first the weight of the samples whose score lies
    // above exactly the grid points 0..k, then summed from the top.
    let (mut n, mut a) = (vec![0.0f64; steps + 2], vec![0.0f64; steps + 2]);
    for s in samples {
        let below = grid.partition_point(|&tau| tau < s.score);
        if below > 0 {
            n[below - 1] += s.weight;
            if s.accepted {
                a[below - 1] += s.weight;
            }
        }
    }
    for k in (0..=steps).rev() {
        n[k] += n[k + 1];
        a[k] += a[k + 1];
    }
    let precision = |k: usize| precision_of(n[k], a[k], m);
    let k = (0..=steps)
        .find(|&k| precision(k).is_none_or(|p| p >= rule.target_precision))
        .unwrap_or(steps);
    OperatingPoint {
        threshold: grid[k].min(1.0),
        estimated_precision: precision(k),
        base_precision: precision(0),
        verdicts: above,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::testing::close;

    fn sample(score: f32, accepted: bool) -> Sample {
        Sample {
            score,
            accepted,
            weight: 1.0,
        }
    }

    fn rule() -> Rule {
        Rule {
            base: 0.36,
            target_precision: 0.98,
            geometry_miss_rate: 0.1,
            min_verdicts: 4,
            max_raise: 0.1,
        }
    }

    #[test]
    fn too_few_verdicts_keep_the_configured_threshold() {
        let samples = [sample(0.5, false), sample(0.6, false), sample(0.3, false)];
        let point = adapt(&rule(), &samples);
        assert_eq!(
            point,
            OperatingPoint {
                verdicts: 2,
                ..OperatingPoint::fixed(0.36)
            }
        );
    }

    /// Ten verdicts above 0.36: nine accepted, one rejected at 0.40.
    /// At τ_0: n = 10, a = 9, T̂ = min(10, 9 / 0.9) = 10, p̂ = 1: the one
    /// rejection is what a 10 % miss rate predicts, so nothing moves.
    #[test]
    fn rejections_the_miss_rate_explains_move_nothing() {
        let mut samples: Vec<Sample> = (0..9)
            .map(|i| sample(0.5 + 0.01 * i as f32, true))
            .collect();
        samples.push(sample(0.40, false));
        let point = adapt(&rule(), &samples);
        assert_eq!(point.threshold, 0.36);
        assert!(close(point.estimated_precision.unwrap() as f32, 1.0));
        assert_eq!(point.verdicts, 10);
    }

    /// Ten accepted at 0.50..0.59 and three rejected at 0.37, 0.38, 0.41.
    /// At τ_0: n = 13, T̂ = min(13, 10 / 0.9 = 11.111), p̂ = 0.854701.
    /// At 0.37 (strictly above): n = 12, p̂ = 11.111 / 12 = 0.925926.
    /// At 0.38: n = 11, p̂ = 1.0 (T̂ capped at 11) ≥ 0.98: chosen.
    #[test]
    fn look_alikes_raise_the_threshold_by_hand() {
        let mut samples: Vec<Sample> = (0..10)
            .map(|i| sample(0.5 + 0.01 * i as f32, true))
            .collect();
        samples.extend([
            sample(0.37, false),
            sample(0.38, false),
            sample(0.41, false),
        ]);
        assert!(close(
            estimated_precision(&samples, 0.36, 0.1).unwrap() as f32,
            0.854_701
        ));
        assert!(close(
            estimated_precision(&samples, 0.37, 0.1).unwrap() as f32,
            0.925_926
        ));
        let point = adapt(&rule(), &samples);
        assert!(close(point.threshold, 0.38));
        assert!(close(point.base_precision.unwrap() as f32, 0.854_701));
        assert!(close(point.estimated_precision.unwrap() as f32, 1.0));
    }

    /// Half of everything rejected at every score: no grid point reaches
    /// the target, so the threshold stops at the top of the grid, 0.46.
    #[test]
    fn the_raise_is_bounded() {
        let samples: Vec<Sample> = (0..20)
            .map(|i| sample(0.4 + 0.02 * i as f32, i % 2 == 0))
            .collect();
        let point = adapt(&rule(), &samples);
        assert!(close(point.threshold, 0.46));
        // At 0.46 (strictly above): scores 0.48..0.78, 16 of them, 8
        // accepted: T̂ = 8 / 0.9 = 8.889, p̂ = 0.555556.
        assert!(close(point.estimated_precision.unwrap() as f32, 0.555_556));
    }

    /// A rejection at the top of the scores with nothing above it: the
    /// first grid point past it judges nothing (n = 0) and is taken.
    #[test]
    fn nothing_left_to_judge_is_taken() {
        let samples = [
            sample(0.40, false),
            sample(0.41, false),
            sample(0.42, false),
            sample(0.43, false),
        ];
        let point = adapt(&rule(), &samples);
        assert!(close(point.threshold, 0.43));
        assert_eq!(point.estimated_precision, None);
        assert!(close(point.base_precision.unwrap() as f32, 0.0));
    }

    /// The one-pass estimate picks what testing every grid point with
    /// [`estimated_precision`] picks, on random samples (scores on and
    /// between the grid points).
    #[test]
    fn one_pass_equals_every_grid_point_tested() {
        let mut rng = crate::synthetic::Rng::new(7);
        for round in 0..200 {
            let samples: Vec<Sample> = (0..5 + round % 60)
                .map(|_| Sample {
                    score: 0.30 + (rng.next() % 300) as f32 / 1000.0,
                    accepted: rng.next() % 100 < 70 + round as u64 % 30,
                    weight: 0.5 + (rng.next() % 100) as f64 / 200.0,
                })
                .collect();
            let r = rule();
            let point = adapt(&r, &samples);
            if point.verdicts < r.min_verdicts {
                continue;
            }
            let grid = (0..=10).map(|k| r.base + k as f32 * GRID_STEP);
            let by_hand = grid
                .clone()
                .find(|&tau| {
                    estimated_precision(&samples, tau, r.geometry_miss_rate)
                        .is_none_or(|p| p >= r.target_precision)
                })
                .unwrap_or(r.base + 10.0 * GRID_STEP);
            assert_eq!(point.threshold, by_hand, "round {round}");
        }
    }

    /// Weights count, not verdicts: a rejection weighing 0.05 (four
    /// half-lives and more old) among nine fresh acceptances and a fresh
    /// rejection: n = 10.05, a = 9, T̂ = 10 (9 / 0.9), p̂ = 0.995025.
    #[test]
    fn old_verdicts_weigh_less() {
        let mut samples: Vec<Sample> = (0..9)
            .map(|i| sample(0.5 + 0.01 * i as f32, true))
            .collect();
        samples.push(sample(0.45, false));
        samples.push(Sample {
            score: 0.40,
            accepted: false,
            weight: 0.05,
        });
        assert!(close(
            estimated_precision(&samples, 0.36, 0.1).unwrap() as f32,
            0.995_025
        ));
        assert_eq!(adapt(&rule(), &samples).threshold, 0.36);
    }
}
