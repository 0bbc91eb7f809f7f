//! Greedy CTC decoding of the PP-OCRv5 recogniser's output.
//!
//! The recogniser emits softmax probabilities `[N, T, C]`: for each of `T`
//! time steps, a distribution over `C` classes, where class 0 is the CTC
//! blank and class `i` is line `i` of the dictionary file (`ppocr_keys_v5.txt`:
//! line 0 is the literal `blank`, the last line is a single space). Greedy
//! decoding, as PaddleOCR's `CTCLabelDecode`, takes the most likely class per
//! step, collapses runs of the same class and drops blanks, so a blank is
//! what separates genuine double letters.
//!
//! The dictionary is kept index-aligned with the model's classes, so the
//! file is parsed line by line without trimming (the final line *is* a
//! space); only a trailing `\r` of Windows line endings is removed. A
//! mismatch between dictionary and model would silently produce garbage, so
//! [`Dictionary::check`] reports it as an error: call it once when the model
//! is loaded. [`decode`] itself never fails: on a mismatch it returns an
//! empty [`Decoded`].

use std::path::{Path, PathBuf};

/// Errors of loading a recogniser dictionary or pairing it with a model.
#[derive(Debug, thiserror::Error)]
pub enum DictionaryError {
    /// The dictionary file could not be read.
    #[error("reading the OCR dictionary {path}: {source}")]
    Io {
        /// The file's path.
        path: PathBuf,
        /// The read error.
        #[source]
        source: std::io::Error,
    },
    /// Fewer than two entries: the blank and at least one character.
    #[error("the OCR dictionary has {0} entries; it needs the blank and at least one character")]
    TooShort(usize),
    /// The first line, given here, is not the CTC blank `blank`.
    #[error("the OCR dictionary's first line is {0:?}; expected the CTC blank \"blank\"")]
    MissingBlank(String),
    /// The recogniser's class count differs from the dictionary's length.
    #[error("the text recogniser outputs {classes} classes but the OCR dictionary has {entries} entries; use the dictionary that belongs to the model")]
    ClassMismatch {
        /// Classes of the recogniser's output.
        classes: usize,
        /// Entries of the dictionary, the blank included.
        entries: usize,
    },
}

/// Characters of the recogniser's classes, index-aligned (entry 0 is the blank).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dictionary {
    entries: Vec<String>,
}

impl Dictionary {
    /// Parses the dictionary file's text: one entry per line, `\n` or
    /// `\r\n`, a final line break optional, a leading byte-order mark ignored.
    /// The first entry must be `blank`.
    pub fn from_lines(text: &str) -> Result<Self, DictionaryError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let text = text.strip_suffix('\n').unwrap_or(text);
        let entries: Vec<String> = text
            .split('\n')
            .map(|line| line.strip_suffix('\r').unwrap_or(line).to_owned())
            .collect();
        if entries.len() < 2 {
            return Err(DictionaryError::TooShort(entries.len()));
        }
        if entries[0] != "blank" {
            return Err(DictionaryError::MissingBlank(entries[0].clone()));
        }
        Ok(Dictionary { entries })
    }

    /// Reads and parses the dictionary file at `path`.
    pub fn load(path: &Path) -> Result<Self, DictionaryError> {
        let text = std::fs::read_to_string(path).map_err(|source| DictionaryError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_lines(&text)
    }

    /// Number of entries, blank included: the model's class count.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Always false for a parsed dictionary (it holds at least the blank).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The text of class `index` (`"blank"` for 0).
    pub fn get(&self, index: usize) -> Option<&str> {
        self.entries.get(index).map(String::as_str)
    }

    /// Whether a model with `classes` output classes fits this dictionary.
    pub fn check(&self, classes: usize) -> Result<(), DictionaryError> {
        if classes == self.len() {
            Ok(())
        } else {
            Err(DictionaryError::ClassMismatch {
                classes,
                entries: self.len(),
            })
        }
    }
}

/// A recognised text line.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Decoded {
    /// The text, surrounding whitespace trimmed.
    pub text: String,
    /// Mean probability of the emitted characters (each run's first step);
    /// 0 when `text` is empty.
    pub confidence: f32,
}

/// Greedy CTC decoding of one sequence: `probs` is `[steps, classes]`
/// row-major. Returns an empty [`Decoded`] when the sizes do not match
/// `probs` or the dictionary (see [`Dictionary::check`]).
pub fn decode(probs: &[f32], steps: usize, classes: usize, dict: &Dictionary) -> Decoded {
    if classes == 0 || classes != dict.len() || steps.checked_mul(classes) != Some(probs.len()) {
        return Decoded::default();
    }
    let mut text = String::new();
    let (mut sum, mut emitted) = (0.0f64, 0usize);
    let mut previous = None;
    for step in probs.chunks_exact(classes) {
        let (class, p) = argmax(step);
        if class != 0 && previous != Some(class) {
            text.push_str(&dict.entries[class]);
            sum += f64::from(p);
            emitted += 1;
        }
        previous = Some(class);
    }
    let trimmed = text.trim();
    if trimmed.is_empty() {
        return Decoded::default();
    }
    Decoded {
        text: trimmed.to_owned(),
        confidence: (sum / emitted as f64) as f32,
    }
}

/// Index and value of the largest entry, the first on ties; NaN never wins,
/// so an all-NaN step decodes as the blank.
fn argmax(values: &[f32]) -> (usize, f32) {
    let mut best = (0, f32::NEG_INFINITY);
    for (i, &v) in values.iter().enumerate() {
        if v > best.1 {
            best = (i, v);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Classes: 0 blank, 1 h, 2 e, 3 l, 4 o, 5 space.
    fn dict() -> Dictionary {
        Dictionary::from_lines("blank\nh\ne\nl\no\n \n").unwrap()
    }

    const C: usize = 6;

    /// One step per `(class, probability)`; the rest of each step's mass is
    /// spread evenly over the other classes.
    fn steps(seq: &[(usize, f32)]) -> Vec<f32> {
        let mut probs = Vec::new();
        for &(class, p) in seq {
            let rest = (1.0 - p) / (C - 1) as f32;
            probs.extend((0..C).map(|c| if c == class { p } else { rest }));
        }
        probs
    }

    #[test]
    fn parses_lines_keeping_the_final_space() {
        let d = Dictionary::from_lines("blank\r\na\r\nb\r\n \r\n").unwrap();
        assert_eq!(d.len(), 4);
        assert_eq!(d.get(0), Some("blank"));
        assert_eq!(d.get(2), Some("b"));
        assert_eq!(d.get(3), Some(" "));
        let no_final_break = Dictionary::from_lines("\u{feff}blank\na\nb\n ").unwrap();
        assert_eq!(no_final_break, d);
        assert!(!d.is_empty());
    }

    #[test]
    fn rejects_bad_dictionaries() {
        assert!(matches!(
            Dictionary::from_lines("blank\n"),
            Err(DictionaryError::TooShort(1))
        ));
        assert!(matches!(
            Dictionary::from_lines("a\nb\n \n"),
            Err(DictionaryError::MissingBlank(first)) if first == "a"
        ));
        let d = dict();
        assert!(d.check(C).is_ok());
        let err = d.check(18385).unwrap_err();
        assert!(err.to_string().contains("18385"), "{err}");
    }

    #[test]
    fn loads_from_a_file() {
        let path = std::env::temp_dir().join(format!("humem-ctc-dict-{}.txt", std::process::id()));
        std::fs::write(&path, "blank\nh\ne\nl\no\n \n").unwrap();
        let loaded = Dictionary::load(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(loaded.unwrap(), dict());
        let missing = Dictionary::load(&path).unwrap_err();
        assert!(matches!(missing, DictionaryError::Io { .. }));
    }

    #[test]
    fn repeats_collapse_and_blanks_separate() {
        // h h e e l _ l o → "hello"; confidence uses each run's first step.
        let seq = [
            (1, 0.9),
            (1, 0.5),
            (2, 0.8),
            (2, 0.7),
            (3, 0.6),
            (0, 0.9),
            (3, 0.7),
            (4, 0.5),
        ];
        let out = decode(&steps(&seq), seq.len(), C, &dict());
        assert_eq!(out.text, "hello");
        let expected = (0.9 + 0.8 + 0.6 + 0.7 + 0.5) / 5.0;
        assert!(
            (out.confidence - expected).abs() < 1e-6,
            "{}",
            out.confidence
        );
    }

    #[test]
    fn repeats_without_blank_are_one_letter() {
        let seq = [(3, 0.9), (3, 0.9), (3, 0.9)];
        assert_eq!(decode(&steps(&seq), 3, C, &dict()).text, "l");
    }

    #[test]
    fn whitespace_is_trimmed_but_inner_space_kept() {
        // " h o " with blanks; the spaces' probabilities still count.
        let seq = [(5, 0.6), (1, 0.8), (5, 0.9), (4, 0.7), (0, 0.9), (5, 0.5)];
        let out = decode(&steps(&seq), seq.len(), C, &dict());
        assert_eq!(out.text, "h o");
        let expected = (0.6 + 0.8 + 0.9 + 0.7 + 0.5) / 5.0;
        assert!((out.confidence - expected).abs() < 1e-6);
    }

    #[test]
    fn empty_outputs() {
        let d = dict();
        let blanks = steps(&[(0, 0.9), (0, 0.8)]);
        assert_eq!(decode(&blanks, 2, C, &d), Decoded::default());
        let spaces = steps(&[(5, 0.9), (0, 0.8), (5, 0.9)]);
        assert_eq!(decode(&spaces, 3, C, &d), Decoded::default());
        assert_eq!(decode(&[], 0, C, &d), Decoded::default());
        assert_eq!(decode(&[f32::NAN; C], 1, C, &d), Decoded::default());
    }

    #[test]
    fn mismatched_sizes_decode_to_nothing() {
        let d = dict();
        let probs = steps(&[(1, 0.9)]);
        assert_eq!(decode(&probs, 2, C, &d), Decoded::default());
        assert_eq!(decode(&probs[..C - 1], 1, C - 1, &d), Decoded::default());
        assert_eq!(decode(&probs, usize::MAX, C, &d), Decoded::default());
        assert_eq!(decode(&probs, 1, 0, &d), Decoded::default());
    }

    proptest! {
        #[test]
        fn never_panics(probs in proptest::collection::vec(-1f32..2.0, 0..60), steps in 0usize..12) {
            let out = decode(&probs, steps, C, &dict());
            prop_assert!(out.confidence.is_finite());
            prop_assert_eq!(out.text.trim(), out.text.as_str());
        }
    }
}
