//! OCR string similarity and distinctiveness, for OGTL.
//!
//! OCR output is noisy in case, punctuation and spacing ("B-214" vs "b214",
//! "EXIT 12" vs "exit 12b"), so every comparison works on a normalised form
//! (lower-case alphanumeric tokens) or a compact form (lower-case
//! alphanumerics only). Similarity takes the strongest of three views
//! (edit distance, token overlap, compact containment) because each one
//! fails on a different kind of OCR error. Distinctiveness decides how much
//! a string can say about *which* place this is: a long, rare, digit-bearing
//! string is a landmark, a generic sign word is not.

use std::collections::BTreeSet;

use crate::vpr::params::VprParams;

/// Lower-case; alphanumerics kept; every run of other characters becomes
/// one space; trimmed. `"  B-214 / EXIT!"` → `"b 214 exit"`.
pub fn normalize(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut gap = false;
    for ch in s.chars() {
        if ch.is_alphanumeric() {
            if gap && !out.is_empty() {
                out.push(' ');
            }
            gap = false;
            out.extend(ch.to_lowercase());
        } else {
            gap = true;
        }
    }
    out
}

/// Lower-case alphanumerics only. `"B-214"` → `"b214"`.
pub fn compact(s: &str) -> String {
    s.chars()
        .filter(|c| c.is_alphanumeric())
        .flat_map(char::to_lowercase)
        .collect()
}

/// `L = 1 − D_lev(a, b) / max(|a|, |b|, 1)` on the normalised strings,
/// lengths in chars (two empty strings give 1, as the formula does).
pub fn levenshtein_similarity(a: &str, b: &str) -> f32 {
    strsim::normalized_levenshtein(&normalize(a), &normalize(b)) as f32
}

/// `J = |tok(a) ∩ tok(b)| / |tok(a) ∪ tok(b)|` on the whitespace tokens of
/// the normalised strings (as sets); 0 when both have no token.
pub fn token_jaccard(a: &str, b: &str) -> f32 {
    let (na, nb) = (normalize(a), normalize(b));
    let ta: BTreeSet<&str> = na.split_whitespace().collect();
    let tb: BTreeSet<&str> = nb.split_whitespace().collect();
    let inter = ta.intersection(&tb).count();
    let union = ta.len() + tb.len() - inter;
    if union == 0 {
        0.0
    } else {
        inter as f32 / union as f32
    }
}

/// `C`: on the compact forms, `|short| / |long|` when the shorter
/// (non-empty) one is contained in the longer, else 0.
pub fn compact_substring(a: &str, b: &str) -> f32 {
    let (ca, cb) = (compact(a), compact(b));
    let (la, lb) = (ca.chars().count(), cb.chars().count());
    let ((short, ls), (long, ll)) = if la <= lb {
        ((ca, la), (cb, lb))
    } else {
        ((cb, lb), (ca, la))
    };
    if ls == 0 || !long.contains(short.as_str()) {
        0.0
    } else {
        ls as f32 / ll as f32
    }
}

/// `S_str(a, b) = max{L(a, b), J(a, b), C(a, b)}`.
pub fn string_similarity(a: &str, b: &str) -> f32 {
    levenshtein_similarity(a, b)
        .max(token_jaccard(a, b))
        .max(compact_substring(a, b))
}

/// How far two strings agree in what tells them apart, for the evidence
/// against a candidate.
///
/// Shop signs share words ("ACME BAKERY 221" and "LUNA BAKERY 48" share
/// "bakery"), which lifts `S_str` to 0.53 although the shops differ. So the
/// tokens (of the normalised forms) that both strings contain are set
/// aside, and `S_str` compares what is left. When nothing is left on one
/// side, one string is a partial read of the other and they agree (1).
/// "KING AVE" and "KINU AVE" compare "king" with "kinu" (0.75): an OCR slip.
pub fn distinct_agreement(a: &str, b: &str) -> f32 {
    let (na, nb) = (normalize(a), normalize(b));
    let ta: BTreeSet<&str> = na.split_whitespace().collect();
    let tb: BTreeSet<&str> = nb.split_whitespace().collect();
    let rest = |own: &str, other: &BTreeSet<&str>| {
        own.split_whitespace()
            .filter(|t| !other.contains(t))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let (ra, rb) = (rest(&na, &tb), rest(&nb, &ta));
    if ra.is_empty() || rb.is_empty() {
        return 1.0;
    }
    string_similarity(&ra, &rb)
}

/// Whether every token of the normalised `text` is one of
/// `params.generic_words` ("OPEN", "NO PARKING"): such a string names no
/// place (an empty string is generic too).
pub fn is_generic(text: &str, params: &VprParams) -> bool {
    normalize(text)
        .split_whitespace()
        .all(|t| params.is_generic_word(t))
}

/// Compact length at which the length term saturates.
const LENGTH_SATURATION: usize = 12;
/// Below this many stored keyframes, document frequencies say nothing and
/// every string counts as rare.
const MIN_DOCUMENTS_FOR_RARITY: u32 = 10;
/// Factor applied to strings made only of generic words.
const GENERIC_FACTOR: f32 = 0.05;

/// Distinctiveness `D_T(u)` ∈ [0, 1] of an OCR string.
///
/// On the compact form `c` (empty → 0) and the normalised form `n`:
/// - `len_f = min(|c|, 12) / 12`, `digit = 1` if `c` has a digit else 0;
/// - `base = min(0.3 + 0.5 len_f + 0.2 digit, 1)`;
/// - rarity `r = 1` if `documents < 10` or `df(n) = 0`, else
///   `clamp(ln(documents / df) / ln(documents), 0, 1)`, where `df` is
///   `document_frequency(n)`, the number of stored keyframes with `n`;
/// - `D = base · (0.5 + 0.5 r)`, times 0.05 when every token of `n` is one
///   of `params.generic_words`.
///
/// So "EXIT" scores ≈ 0.023, "B-214" ≈ 0.667 in a small store, and a
/// string seen in every keyframe keeps only half of its base weight.
pub fn distinctiveness(
    text: &str,
    document_frequency: &dyn Fn(&str) -> u32,
    documents: u32,
    params: &VprParams,
) -> f32 {
    let c = compact(text);
    let len = c.chars().count();
    if len == 0 {
        return 0.0;
    }
    let len_f = len.min(LENGTH_SATURATION) as f32 / LENGTH_SATURATION as f32;
    let digit = if c.chars().any(char::is_numeric) {
        1.0
    } else {
        0.0
    };
    let base = (0.3 + 0.5 * len_f + 0.2 * digit).min(1.0);

    let n = normalize(text);
    let rarity = if documents < MIN_DOCUMENTS_FOR_RARITY {
        1.0
    } else {
        match document_frequency(&n) {
            0 => 1.0,
            df => {
                let r = (f64::from(documents) / f64::from(df)).ln() / f64::from(documents).ln();
                r.clamp(0.0, 1.0) as f32
            }
        }
    };
    let d = base * (0.5 + 0.5 * rarity);
    if is_generic(text, params) {
        d * GENERIC_FACTOR
    } else {
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-5
    }

    fn none(_: &str) -> u32 {
        0
    }

    #[test]
    fn normalize_and_compact() {
        assert_eq!(normalize("  B-214 / EXIT!"), "b 214 exit");
        assert_eq!(normalize("Rue--de  la...Paix"), "rue de la paix");
        assert_eq!(normalize("!!!"), "");
        assert_eq!(normalize("ÉCOLE 3"), "école 3");
        assert_eq!(compact("B-214"), "b214");
        assert_eq!(compact(" Exit 12b "), "exit12b");
    }

    #[test]
    fn distinct_agreement_sets_shared_words_aside() {
        // S_str("LUNA BAKERY 48", "ACME BAKERY 221") = 1 − 7/15 = 0.533333
        // (Levenshtein), but the shops differ: without "bakery",
        // "luna 48" vs "acme 221" gives L = 1 − 7/8 = 0.125, J = 0, C = 0.
        assert!(close(
            string_similarity("LUNA BAKERY 48", "ACME BAKERY 221"),
            0.533333
        ));
        assert!(close(
            distinct_agreement("LUNA BAKERY 48", "ACME BAKERY 221"),
            0.125
        ));
        // An OCR slip: "king" vs "kinu", L = 0.75.
        assert!(close(distinct_agreement("KING AVE", "KINU AVE"), 0.75));
        // A partial read agrees fully; so do equal strings.
        assert_eq!(distinct_agreement("DENTAL", "ACME DENTAL"), 1.0);
        assert_eq!(distinct_agreement("B-214", "b 214"), 1.0);
        // Nothing shared: plain S_str ("b214" inside "b2145": 4/5).
        assert!(close(distinct_agreement("B214", "B2145"), 0.8));
    }

    #[test]
    fn exit_12_vs_exit_12b() {
        // Normalised "exit 12" (7 chars) vs "exit 12b" (8): one insertion,
        // L = 1 − 1/8 = 0.875.
        assert!(close(levenshtein_similarity("EXIT 12", "exit 12b"), 0.875));
        // Tokens {exit, 12} vs {exit, 12b}: 1 shared of 3, J = 1/3.
        assert!(close(token_jaccard("EXIT 12", "exit 12b"), 1.0 / 3.0));
        // Compact "exit12" (6) inside "exit12b" (7): C = 6/7 = 0.857143.
        assert!(close(compact_substring("EXIT 12", "exit 12b"), 6.0 / 7.0));
        // S_str = max(0.875, 0.333, 0.857) = 0.875.
        assert!(close(string_similarity("EXIT 12", "exit 12b"), 0.875));
    }

    #[test]
    fn each_view_can_win() {
        // Word order: L("main street", "street main") = 1 − 8/11 ≈ 0.27,
        // C = 0 (not contained), J = 2/2 = 1.
        assert!(close(token_jaccard("Main Street", "street main"), 1.0));
        assert!(close(string_similarity("Main Street", "street main"), 1.0));
        // Spacing/punctuation: "b 214" vs "b214": L = 1 − 1/5 = 0.8, J = 0,
        // C = 4/4 = 1.
        assert!(close(levenshtein_similarity("B-214", "b214"), 0.8));
        assert!(close(token_jaccard("B-214", "b214"), 0.0));
        assert!(close(string_similarity("B-214", "b214"), 1.0));
        // Substring: compact "214" in "b214": C = 3/4.
        assert!(close(compact_substring("214", "B214"), 0.75));
        // Nothing in common.
        assert!(close(string_similarity("exit", "b214"), 0.0));
    }

    #[test]
    fn empty_strings() {
        assert!(close(token_jaccard("", "!!"), 0.0));
        assert!(close(compact_substring("", "abc"), 0.0));
        assert!(close(compact_substring("", ""), 0.0));
        // L(∅, ∅) = 1 − 0/max(0, 0, 1) = 1, literally the formula; such a
        // string has D_T = 0, so it never carries weight in S_T.
        assert!(close(levenshtein_similarity("", "--"), 1.0));
        assert!(close(levenshtein_similarity("", "ab"), 0.0));
    }

    #[test]
    fn levenshtein_counts_chars_not_bytes() {
        // "café" vs "cafe": one substitution over 4 chars (5 bytes): 0.75.
        assert!(close(levenshtein_similarity("café", "cafe"), 0.75));
    }

    #[test]
    fn generic_word_is_near_zero_and_codes_are_high() {
        let p = VprParams::default();
        // "EXIT": |c| = 4, len_f = 1/3, no digit: base = 0.3 + 0.5/3 =
        // 0.466667; small store → r = 1 → 0.466667; generic → × 0.05 = 0.023333.
        assert!(close(distinctiveness("EXIT", &none, 3, &p), 0.023333));
        // "NO PARKING": every token generic: c = "noparking" (9), base =
        // 0.3 + 0.5·0.75 = 0.675, × 0.05 = 0.03375.
        assert!(close(distinctiveness("NO PARKING", &none, 3, &p), 0.03375));
        // "B-214": c = "b214" (4), digit: base = 0.3 + 0.166667 + 0.2 = 0.666667.
        assert!(close(distinctiveness("B-214", &none, 3, &p), 0.666667));
        // "EXIT 12": "12" is not generic: c = "exit12" (6), base = 0.3 +
        // 0.25 + 0.2 = 0.75.
        assert!(close(distinctiveness("EXIT 12", &none, 3, &p), 0.75));
        // Long and numbered saturates: "Rue de la Paix 12" → 13 chars:
        // 0.3 + 0.5 + 0.2 = 1.0.
        assert!(close(
            distinctiveness("Rue de la Paix 12", &none, 3, &p),
            1.0
        ));
        // Nothing readable.
        assert!(close(distinctiveness("--", &none, 3, &p), 0.0));
    }

    #[test]
    fn rarity_from_document_frequency() {
        let p = VprParams::default();
        // N = 100, df("b 214") = 10: r = ln(10)/ln(100) = 0.5, D = 0.666667 ·
        // (0.5 + 0.25) = 0.5.
        let df = |s: &str| if s == "b 214" { 10 } else { 0 };
        assert!(close(distinctiveness("B-214", &df, 100, &p), 0.5));
        // df = N: r = 0, D = base / 2 = 0.333333.
        let everywhere = |_: &str| 100;
        assert!(close(
            distinctiveness("B-214", &everywhere, 100, &p),
            0.333333
        ));
        // df = 1: r = ln(100)/ln(100) = 1: full base.
        let once = |_: &str| 1;
        assert!(close(distinctiveness("B-214", &once, 100, &p), 0.666667));
        // df = 0 (not stored yet): rare.
        assert!(close(distinctiveness("B-214", &none, 100, &p), 0.666667));
        // Fewer than 10 keyframes: frequencies are ignored.
        assert!(close(
            distinctiveness("B-214", &everywhere, 9, &p),
            0.666667
        ));
        // df > N (inconsistent source) clamps to r = 0.
        let too_many = |_: &str| 500;
        assert!(close(
            distinctiveness("B-214", &too_many, 100, &p),
            0.333333
        ));
    }
}
