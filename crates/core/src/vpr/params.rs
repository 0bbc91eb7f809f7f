//! Every HuMem-VPR constant, with the paper's values as defaults.
//!
//! The parameters are one plain, serde-(de)serialisable struct so that the
//! service configuration can override any of them (unknown keys are rejected,
//! missing keys take the paper's value), and [`VprParams::validate`] checks
//! the ranges once at load time so the scoring code can trust them. Which
//! corroborating layers run is a separate value, [`Layers`]: the paper's
//! ablations are configurations, not code branches.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::vpr::feedback::VerdictParams;

/// Which pass scores the store (`vpr.scan`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ScanMode {
    /// Compressed from [`COMPRESSED_MIN_ROWS`](crate::vpr::scan::COMPRESSED_MIN_ROWS) stored rows where the CPU
    /// has a fast code kernel, exact otherwise.
    #[default]
    Auto,
    /// Always the f32 pass.
    Exact,
    /// Always the code pass with exact re-scoring (same results).
    Compressed,
}

/// Tunable constants of the scoring (defaults from the paper, `docs/scoring.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VprParams {
    /// `λ_c`, strength of the scene-class modulation of `s_e`.
    pub lambda_c: f32,
    /// `w`, weight of the appearance thumbnails' similarity in `s_e`
    /// (`vpr::appearance`; 0, the default, turns the channel off). 0.1–0.15
    /// raise the mean R@1 over the dev data sets by 0.055–0.065 but widen
    /// the null, so that at the 2 % false-alarm operating point fewer
    /// queries are answered (docs/evaluation.md, "Perception quality").
    pub appearance_weight: f32,
    /// `α`, temporal weights of the current observation and its two predecessors.
    pub alpha: [f32; 3],
    /// How the temporal average enters `S_s`: `support` (default) takes
    /// `max(s̃_e, average)`, so a consistent history raises the score and a
    /// missing or misaligned one never lowers it; `average` is the paper's
    /// formula as written.
    pub temporal: TemporalMode,
    /// `K`, number of SCAL candidates passed to OSRL and OGTL.
    pub top_k: usize,
    /// Which pass scores the store: `auto` (default) scans the one-byte
    /// codes first on large stores and re-scores exactly, `exact` always
    /// reads the f32 descriptors, `compressed` always the codes first. All
    /// three give the same answer ([`super::scan`]).
    pub scan: ScanMode,
    /// Never take a query's candidates from the neighbour graph: every
    /// answer comes from a full pass over the eligible keyframes.
    pub exact: bool,
    /// Eligible keyframes (the rows of the maps a query may see) from
    /// which a query's SCAL candidates come from the store's neighbour
    /// graph, where it keeps one, instead of a pass over all of them
    /// ([`super::scan`]); below it the pass is exact.
    pub approximate_from: usize,
    /// The smallest share of the stored keyframes a query's eligible ones
    /// must be for the neighbour graph to propose its candidates. The
    /// graph's walk is filtered: a selective filter (one robot's map of a
    /// large fleet's store) makes it visit many keyframes for each one it
    /// may propose, and an exact pass over the eligible keyframes' own
    /// partition costs less (`humem bench graph --scopes one-robot`).
    pub approximate_min_share: f32,
    /// Candidates the neighbour graph proposes; each is scored exactly
    /// and the best `top_k` go on. More find the exact answer more often
    /// and cost more.
    pub approximate_candidates: usize,
    /// `λ_a`, weight of the area difference in the layout distance `d²`.
    pub lambda_a: f32,
    /// `σ_m`, width of the Gaussian spatial kernel `G`.
    pub sigma_m: f32,
    /// `τ_g`, minimum `G` for two objects' texts to be compared.
    pub tau_g: f32,
    /// `g_o`, gain of the object evidence in `B`.
    pub g_o: f32,
    /// `g_t`, gain of the text evidence in `B`.
    pub g_t: f32,
    /// How the score that the threshold applies to is made: `null`
    /// (default) calibrates the scene score against this query's own scores
    /// on the eligible store; `raw` is the paper's rule, the threshold on
    /// `Λ` itself (see [`Calibration`]).
    pub calibration: Calibration,
    /// `τ_s`, the paper's selection threshold on the raw `Λ` (strict), used
    /// with `calibration = "raw"`.
    pub tau_s: f32,
    /// `τ_c`, the selection threshold on the calibrated score (strict), used
    /// with `calibration = "null"`. Chosen on the mean over every dev data
    /// set (docs/scoring.md, "Operating point").
    pub tau_c: f32,
    /// Fewest eligible keyframes for a calibrated answer: below this the
    /// query's null distribution is not known and every calibrated score
    /// is 0, so nothing passes the threshold.
    pub null_min_samples: usize,
    /// `τ_x`, string agreement at or above which two distinctive texts
    /// agree (OCR slips keep `S_str` high); below it they contradict.
    pub contradiction_agreement: f32,
    /// `g_xt`, gain of disagreeing distinctive text in the contradiction `C`.
    pub g_xt: f32,
    /// `g_xo`, gain of missing distinctive objects in `C`.
    pub g_xo: f32,
    /// Smallest area (share of the image) of a distinctive object whose
    /// absence on the other side counts against a candidate by its size
    /// alone, where that side read some text (its OCR could read); a
    /// smaller one counts only where the other side read text near its
    /// place.
    pub absence_min_area: f32,
    /// Maximum number of selected candidates.
    pub max_candidates: usize,
    /// Largest rotation, in degrees, between the camera of a query and
    /// that of a candidate of its own map ([`super::viewpoint`]): one
    /// turned further away cannot show the same place to a perspective
    /// camera and is left out. 180: off (fisheye and 360° cameras).
    pub max_view_change_deg: f64,
    /// The drift envelope's bound ([`super::drift`]): a candidate of the
    /// query's own map lying farther from it than this share of the path
    /// between them, plus the same-place radius, loses score, up to
    /// [`super::drift::PENALTY`] at twice the share. 1: off (maps whose
    /// poses are not one continuous odometry).
    pub max_drift_ratio: f64,
    /// Whether a candidate of the query's own map beyond the drift
    /// envelope is left out when one within it ranks above it
    /// ([`super::drift`]): the map already explains the query by a place
    /// it allows, and a rival it does not allow would only cost SLAM a
    /// geometric check (or bend the map). Nothing changes where no
    /// candidate within the envelope ranks higher, so the top candidate
    /// and the recall at the threshold are what the envelope alone gives.
    /// Off by default: in drifting replays the candidates it left out were
    /// true revisits (docs/scoring.md).
    pub leave_out_rivals_beyond_drift: bool,
    /// `ω_r`, importance of semantic class `r` in `S_o`.
    pub class_weights: BTreeMap<String, f32>,
    /// `ω_r` of classes not listed in `class_weights`.
    pub default_class_weight: f32,
    /// Lower-case single words that make a string generic (near-zero
    /// distinctiveness) when every token of it is one of them.
    pub generic_words: Vec<String>,
    /// How SLAM's geometric verdicts change rankings (`[vpr.verdicts]`,
    /// see [`super::feedback`]).
    pub verdicts: VerdictParams,
}

/// Common sign words that say nothing about which place this is.
const GENERIC_WORDS: &[&str] = &[
    "exit", "open", "closed", "parking", "stop", "entrance", "enter", "push", "pull", "toilet",
    "toilets", "wc", "sale", "welcome", "no", "in", "out", "the", "and", "of", "to", "for", "on",
    "off", "way", "one", "only", "info", "keep", "left", "right", "caution", "danger", "private",
    "police", "taxi",
];

/// Default `w` (see [`VprParams::appearance_weight`]).
pub const APPEARANCE_WEIGHT: f32 = 0.0;

/// Default `τ_c` (see [`VprParams::tau_c`]).
pub const TAU_C: f32 = 0.36;

/// Which score the selection threshold applies to.
///
/// The raw cosine scale depends on the descriptor model: the paper's
/// `τ_s = 0.70` was set for EigenPlaces, while the default EfficientNet GeM
/// descriptor scores unrelated places around 0.8. `null` therefore
/// calibrates per query (see [`super::calibration`]); `raw` keeps the
/// paper's rule so ablations stay comparable with the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Calibration {
    /// Threshold `τ_c` on `Λ_c = c_s (1 − C) + (1 − c_s) B`, with `c_s` the
    /// scene score calibrated against this query's null distribution.
    Null,
    /// Threshold `τ_s` on the paper's `Λ = S_s + (1 − S_s) B`.
    Raw,
}

/// How SCAL's temporal context combines with the current pair.
///
/// The paper averages `s̃_e` over the current pair and up to two preceding
/// pairs, renormalising `α` to the history available. Measured with the
/// default EfficientNet-Lite0 GeM descriptor (R@1, frame-gap protocol):
/// rtabmap-loop 0.955 without temporal context, 0.886 with the average,
/// 0.977 with `support`; town-dev loop 0.981 / 0.986 / 0.986. The average
/// loses where a revisit's keyframes are not spaced like the first pass and
/// favours candidates with no predecessors (their score is `s̃_e` alone), so
/// the default lets the history corroborate but not veto, as the object and
/// text layers do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TemporalMode {
    /// `S_s = max(s̃_e(Q_t, C_i), Σ_j α_j s̃_e(Q_{t−j}, C_{i−j}) / Σ_j α_j)`.
    Support,
    /// `S_s = Σ_j α_j s̃_e(Q_{t−j}, C_{i−j}) / Σ_j α_j` (the paper).
    Average,
}

/// Default of [`VprParams::approximate_from`]: where a query over the
/// neighbour graph's candidates costs about half the exact pass over every
/// eligible row (they cost the same near 12 000 at 1280 values, `humem
/// bench graph`); below it every answer is exact, which covers a loop
/// query over any one robot's map of up to that many keyframes.
pub const APPROXIMATE_FROM: usize = 20_000;

/// Default of [`VprParams::approximate_min_share`]: at a million
/// keyframes × 1280 values, a loop query over one robot's map of 31 000
/// (3 % of the store) through the graph took about twice what the exact
/// pass over that map took, under a fleet's load; by the costs measured
/// there the two meet near 5 %.
pub const APPROXIMATE_MIN_SHARE: f32 = 1.0 / 16.0;

/// Default of [`VprParams::approximate_candidates`]. A place a fleet
/// passes again and again holds a couple of hundred near-identical
/// keyframes in a store of a million, and the exact best of them is found
/// only where the walk proposes it: under a 32-robot load on 1.04M
/// keyframes (`humem load --scopes same-map,other-maps --exact-every
/// 10`), 100 candidates gave the exact top candidate for 87-89 % of
/// merge queries (98-99 % one at its place), 256 for 99.6 % (100 %), at
/// about 2 % fewer queries answered.
pub const APPROXIMATE_CANDIDATES: usize = 256;

impl Default for VprParams {
    fn default() -> Self {
        VprParams {
            lambda_c: 0.10,
            appearance_weight: APPEARANCE_WEIGHT,
            alpha: [0.5, 0.3, 0.2],
            temporal: TemporalMode::Support,
            top_k: 25,
            scan: ScanMode::Auto,
            exact: false,
            approximate_from: APPROXIMATE_FROM,
            approximate_min_share: APPROXIMATE_MIN_SHARE,
            approximate_candidates: APPROXIMATE_CANDIDATES,
            lambda_a: 1.0,
            sigma_m: 0.25,
            tau_g: 0.6,
            g_o: 0.15,
            g_t: 0.25,
            calibration: Calibration::Null,
            tau_s: 0.70,
            tau_c: TAU_C,
            null_min_samples: 10,
            contradiction_agreement: 0.5,
            g_xt: 1.0,
            g_xo: 0.5,
            absence_min_area: 0.01,
            max_candidates: 5,
            max_view_change_deg: 60.0,
            max_drift_ratio: 0.05,
            leave_out_rivals_beyond_drift: false,
            class_weights: BTreeMap::new(),
            default_class_weight: 1.0,
            generic_words: GENERIC_WORDS.iter().map(|w| w.to_string()).collect(),
            verdicts: VerdictParams::default(),
        }
    }
}

impl VprParams {
    /// `ω_r`: the configured weight of `class`, or `default_class_weight`.
    pub fn class_weight(&self, class: &str) -> f32 {
        self.class_weights
            .get(class)
            .copied()
            .unwrap_or(self.default_class_weight)
    }

    /// The default selection threshold for this calibration.
    pub fn threshold(&self) -> f32 {
        match self.calibration {
            Calibration::Null => self.tau_c,
            Calibration::Raw => self.tau_s,
        }
    }

    /// Whether `token` (already normalised) is one of the generic words.
    pub fn is_generic_word(&self, token: &str) -> bool {
        self.generic_words.iter().any(|w| w == token)
    }

    /// Checks every range; the error message names the offending field.
    pub fn validate(&self) -> Result<(), String> {
        fn finite_in(name: &str, v: f32, lo: f32, hi: f32) -> Result<(), String> {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(format!("{name} must be in [{lo}, {hi}], got {v}"))
            }
        }
        fn non_negative(name: &str, v: f32) -> Result<(), String> {
            finite_in(name, v, 0.0, f32::MAX)
        }

        non_negative("lambda_c", self.lambda_c)?;
        finite_in("appearance_weight", self.appearance_weight, 0.0, 1.0)?;
        for (j, a) in self.alpha.iter().enumerate() {
            non_negative(&format!("alpha[{j}]"), *a)?;
        }
        // S_s renormalises the α actually used; the current observation is
        // always used, so it must carry weight or the denominator can be 0.
        if self.alpha[0] <= 0.0 {
            return Err(format!(
                "alpha[0] must be > 0 (the current observation always counts), got {}",
                self.alpha[0]
            ));
        }
        if self.top_k == 0 {
            return Err("top_k must be >= 1".to_string());
        }
        if self.approximate_candidates == 0 {
            return Err("approximate_candidates must be >= 1".to_string());
        }
        finite_in(
            "approximate_min_share",
            self.approximate_min_share,
            0.0,
            1.0,
        )?;
        non_negative("lambda_a", self.lambda_a)?;
        if !(self.sigma_m.is_finite() && self.sigma_m > 0.0) {
            return Err(format!("sigma_m must be > 0, got {}", self.sigma_m));
        }
        finite_in("tau_g", self.tau_g, 0.0, 1.0)?;
        non_negative("g_o", self.g_o)?;
        non_negative("g_t", self.g_t)?;
        finite_in("tau_s", self.tau_s, 0.0, 1.0)?;
        finite_in("tau_c", self.tau_c, 0.0, 1.0)?;
        if self.null_min_samples == 0 {
            return Err("null_min_samples must be >= 1".to_string());
        }
        finite_in(
            "contradiction_agreement",
            self.contradiction_agreement,
            0.0,
            1.0,
        )?;
        non_negative("g_xt", self.g_xt)?;
        non_negative("g_xo", self.g_xo)?;
        finite_in("absence_min_area", self.absence_min_area, 0.0, 1.0)?;
        if self.max_candidates == 0 {
            return Err("max_candidates must be >= 1".to_string());
        }
        if !(self.max_view_change_deg > 0.0 && self.max_view_change_deg <= 180.0) {
            return Err("max_view_change_deg must be in (0, 180]".to_string());
        }
        if !(self.max_drift_ratio > 0.0 && self.max_drift_ratio <= 1.0) {
            return Err("max_drift_ratio must be in (0, 1]".to_string());
        }
        for (class, w) in &self.class_weights {
            non_negative(&format!("class_weights[{class}]"), *w)?;
        }
        non_negative("default_class_weight", self.default_class_weight)?;
        for w in &self.generic_words {
            let ok = !w.is_empty() && w.chars().all(|c| c.is_alphanumeric() && !c.is_uppercase());
            if !ok {
                return Err(format!(
                    "generic_words must be single lower-case alphanumeric words, got {w:?}"
                ));
            }
        }
        self.verdicts.validate()?;
        Ok(())
    }
}

/// Which corroborating layers run (SCAL always runs). Ablations are
/// configurations: a layer that is off contributes 0 to `B`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layers {
    /// Object-spatial reasoning (`S_o`).
    pub osrl: bool,
    /// Object-grounded text (`S_t`, `E_t`); objects still gate it.
    pub ogtl: bool,
    /// Evidence against a candidate (`C`: disagreeing distinctive text,
    /// missing distinctive objects); off, evidence can only raise `Λ`, as
    /// in the paper.
    pub contradiction: bool,
}

impl Layers {
    /// Scene context only.
    pub const SCAL: Layers = Layers {
        osrl: false,
        ogtl: false,
        contradiction: false,
    };
    /// Scene context and object layout.
    pub const SCAL_OSRL: Layers = Layers {
        osrl: true,
        ogtl: false,
        contradiction: false,
    };
    /// Scene context and grounded text.
    pub const SCAL_OGTL: Layers = Layers {
        osrl: false,
        ogtl: true,
        contradiction: false,
    };
    /// All three layers, with the evidence against a candidate.
    pub const FULL: Layers = Layers {
        osrl: true,
        ogtl: true,
        contradiction: true,
    };
    /// All three layers, evidence only for (the paper's full method; the
    /// ablation of the contradiction).
    pub const FULL_SUPPORT_ONLY: Layers = Layers {
        osrl: true,
        ogtl: true,
        contradiction: false,
    };
}

impl Default for Layers {
    fn default() -> Self {
        Layers::FULL
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_paper_constants_and_valid() {
        let p = VprParams::default();
        assert_eq!(p.lambda_c, 0.10);
        assert_eq!(p.alpha, [0.5, 0.3, 0.2]);
        assert_eq!(p.top_k, 25);
        assert_eq!(p.lambda_a, 1.0);
        assert_eq!(p.sigma_m, 0.25);
        assert_eq!(p.tau_g, 0.6);
        assert_eq!(p.g_o, 0.15);
        assert_eq!(p.g_t, 0.25);
        assert_eq!(p.tau_s, 0.70);
        assert_eq!(p.calibration, Calibration::Null);
        assert_eq!(p.threshold(), TAU_C);
        let raw = VprParams {
            calibration: Calibration::Raw,
            ..VprParams::default()
        };
        assert_eq!(raw.threshold(), 0.70);
        assert_eq!(p.max_candidates, 5);
        assert!(p.is_generic_word("exit"));
        assert!(!p.is_generic_word("b214"));
        assert_eq!(p.validate(), Ok(()));
    }

    #[test]
    fn class_weight_falls_back_to_default() {
        let mut p = VprParams::default();
        p.class_weights.insert("building".into(), 2.0);
        p.default_class_weight = 0.5;
        assert_eq!(p.class_weight("building"), 2.0);
        assert_eq!(p.class_weight("fence"), 0.5);
    }

    type Mutation = Box<dyn Fn(&mut VprParams)>;

    #[test]
    fn validate_names_the_field() {
        let cases: Vec<(&str, Mutation)> = vec![
            ("lambda_c", Box::new(|p| p.lambda_c = -0.1)),
            ("alpha[1]", Box::new(|p| p.alpha[1] = -1.0)),
            ("alpha[0]", Box::new(|p| p.alpha = [0.0, 0.5, 0.5])),
            ("top_k", Box::new(|p| p.top_k = 0)),
            ("lambda_a", Box::new(|p| p.lambda_a = f32::NAN)),
            ("sigma_m", Box::new(|p| p.sigma_m = 0.0)),
            ("tau_g", Box::new(|p| p.tau_g = 1.5)),
            ("g_o", Box::new(|p| p.g_o = -0.15)),
            ("g_t", Box::new(|p| p.g_t = f32::INFINITY)),
            ("tau_s", Box::new(|p| p.tau_s = -0.1)),
            ("tau_c", Box::new(|p| p.tau_c = 1.5)),
            ("null_min_samples", Box::new(|p| p.null_min_samples = 0)),
            (
                "contradiction_agreement",
                Box::new(|p| p.contradiction_agreement = f32::NAN),
            ),
            ("g_xt", Box::new(|p| p.g_xt = -1.0)),
            ("g_xo", Box::new(|p| p.g_xo = f32::INFINITY)),
            ("absence_min_area", Box::new(|p| p.absence_min_area = 2.0)),
            ("max_candidates", Box::new(|p| p.max_candidates = 0)),
            (
                "max_view_change_deg",
                Box::new(|p| p.max_view_change_deg = f64::NAN),
            ),
            ("max_drift_ratio", Box::new(|p| p.max_drift_ratio = 0.0)),
            (
                "class_weights[sign]",
                Box::new(|p| {
                    p.class_weights.insert("sign".into(), -1.0);
                }),
            ),
            (
                "default_class_weight",
                Box::new(|p| p.default_class_weight = -1.0),
            ),
            (
                "generic_words",
                Box::new(|p| p.generic_words.push("No Entry".into())),
            ),
        ];
        for (field, mutate) in cases {
            let mut p = VprParams::default();
            mutate(&mut p);
            let err = p.validate().expect_err(field);
            assert!(err.contains(field), "{err:?} should name {field}");
        }
    }

    #[test]
    fn layers_constants() {
        let l = |osrl, ogtl, contradiction| Layers {
            osrl,
            ogtl,
            contradiction,
        };
        assert_eq!(Layers::SCAL, l(false, false, false));
        assert_eq!(Layers::SCAL_OSRL, l(true, false, false));
        assert_eq!(Layers::SCAL_OGTL, l(false, true, false));
        assert_eq!(Layers::FULL, l(true, true, true));
        assert_eq!(Layers::FULL_SUPPORT_ONLY, l(true, true, false));
        assert_eq!(Layers::default(), Layers::FULL);
    }
}
