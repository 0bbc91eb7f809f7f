//! Text recall of the OCR (`humem text-recall`): of the frames that have a
//! distinctive sign in view, the share in which OCR reads that sign's
//! string, and the OCR time per image.
//!
//! OGTL can only ground what OCR reads, so this measures the reading on its
//! own, from the data set's ground truth rather than from place recall:
//! - a sign is one of `objects.json`'s objects with a *distinctive* text: a
//!   place name of two words or more that is not made of generic sign words
//!   ("ACME BAKERY 221", "CEDAR AVE"; not "OPEN", "NO PARKING", "30");
//! - it is *in view* of a frame when its centre lies within 15 m of the
//!   camera (the frame's pose), in front of it and inside the image (the
//!   sequence's pinhole calibration), and, where the data set has instance
//!   masks, at least [`MIN_VISIBLE_PIXELS`] of it are visible (not hidden
//!   behind a building);
//! - it is *read* when its compact form (lower-case alphanumerics) occurs in
//!   the frame's OCR text (every line, in reading order, compacted and
//!   joined) with at most one edit in five characters
//!   ([`approximate_occurrence`]), so a sign read as two lines, or as one
//!   line with its neighbour, still counts.
//!
//! Frames are read one at a time, so the time per image is the OCR's
//! latency, not a batch's throughput.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use nalgebra::Vector3;
use serde::Serialize;

use super::annotations::{self, Catalog};
use super::dataset::image_paths;
use super::truth::{self, Pose};
use humem_core::vpr::params::VprParams;
use humem_core::vpr::text::{compact, is_generic, normalize};
use humem_perception::{ImageInput, Perception};
use humem_server::config::Config;

/// Farthest a sign may be to count as in view, metres.
pub const MAX_DISTANCE_M: f64 = 15.0;
/// Fewest visible mask pixels of a sign in view.
pub const MIN_VISIBLE_PIXELS: u32 = 30;
/// Edits allowed per this many characters of a sign's compact text.
const CHARS_PER_EDIT: usize = 5;

/// Options of `humem text-recall`.
#[derive(Debug, Clone, clap::Args)]
pub struct TextRecallArgs {
    /// Data set folders with poses, calibration and an `objects.json` in the
    /// folder or its parent (e.g. town-dev/loop, town-dev/rain_fog);
    /// repeatable. The query images are read (for `loop`, the sequence).
    #[arg(long, required = true)]
    pub dataset: Vec<PathBuf>,
    /// Only the frames whose index is in this range (`START..END`, END
    /// excluded), e.g. to check a few frames quickly.
    #[arg(long, value_parser = parse_range)]
    pub frames: Option<std::ops::Range<usize>>,
    /// Read every this many frames only: a SLAM system's keyframes are
    /// sparser than a data set's frames, which matters where
    /// `perception.reuse` carries text over between similar keyframes.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub stride: u32,
    /// Write every number as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Parses `START..END`.
fn parse_range(text: &str) -> Result<std::ops::Range<usize>, String> {
    let (start, end) = text
        .split_once("..")
        .ok_or_else(|| format!("{text:?}: expected START..END"))?;
    let number = |s: &str| {
        s.trim()
            .parse::<usize>()
            .map_err(|e| format!("{text:?}: {s:?} is not a frame index: {e}"))
    };
    let (start, end) = (number(start)?, number(end)?);
    if start >= end {
        return Err(format!("{text:?}: the range is empty"));
    }
    Ok(start..end)
}

/// A pinhole camera, from `<sequence>_calib.json`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
pub struct Pinhole {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal focal length, pixels.
    pub fx: f64,
    /// Vertical focal length, pixels.
    pub fy: f64,
    /// Principal point's x, pixels.
    pub cx: f64,
    /// Principal point's y, pixels.
    pub cy: f64,
}

/// A sign with distinctive text and where it stands.
#[derive(Debug, Clone, PartialEq)]
pub struct Sign {
    /// Its instance id in `objects.json` and the masks.
    pub id: u16,
    /// The text it carries, as the catalog writes it.
    pub text: String,
    /// Its centre in the world frame, metres.
    pub position: Vector3<f64>,
}

/// Whether `text` names a place: two or more words, not all generic.
pub fn is_distinctive(text: &str, params: &VprParams) -> bool {
    normalize(text).split_whitespace().count() >= 2 && !is_generic(text, params)
}

/// The catalog's objects with distinctive text and a position.
pub fn signs(catalog: &Catalog, params: &VprParams) -> Vec<Sign> {
    let mut signs: Vec<Sign> = catalog
        .objects
        .iter()
        .filter_map(|(&id, o)| {
            let text = o.text.as_ref()?;
            let [x, y, z] = o.position?;
            is_distinctive(text, params).then(|| Sign {
                id,
                text: text.clone(),
                position: Vector3::new(x, y, z),
            })
        })
        .collect();
    signs.sort_by_key(|s| s.id);
    signs
}

/// Whether `point` (world frame) is within `MAX_DISTANCE_M` of the camera at
/// `pose` (camera-to-world, OpenCV axes), in front of it and inside its image.
pub fn in_view(point: &Vector3<f64>, pose: &Pose, camera: &Pinhole) -> bool {
    let offset = point - pose.t;
    if offset.norm() > MAX_DISTANCE_M {
        return false;
    }
    let p = pose.r.inverse() * offset;
    if p.z <= 0.1 {
        return false;
    }
    let u = camera.fx * p.x / p.z + camera.cx;
    let v = camera.fy * p.y / p.z + camera.cy;
    (0.0..camera.width as f64).contains(&u) && (0.0..camera.height as f64).contains(&v)
}

/// The fewest edits that turn `needle` into some substring of `haystack`
/// (Sellers' semi-global edit distance), in chars.
pub fn substring_distance(needle: &str, haystack: &str) -> usize {
    let needle: Vec<char> = needle.chars().collect();
    // Column per needle prefix: edits to match it ending at this position.
    let mut column: Vec<usize> = (0..=needle.len()).collect();
    let mut best = needle.len();
    for h in haystack.chars() {
        let mut diagonal = column[0];
        column[0] = 0; // a match may start anywhere
        for (i, &n) in needle.iter().enumerate() {
            let substitute = diagonal + usize::from(n != h);
            diagonal = column[i + 1];
            column[i + 1] = substitute.min(column[i] + 1).min(diagonal + 1);
        }
        best = best.min(column[needle.len()]);
    }
    best
}

/// Whether `sign` occurs in the lines read (see the module docs).
pub fn approximate_occurrence(sign: &str, lines: &[String]) -> bool {
    let needle = compact(sign);
    if needle.is_empty() {
        return false;
    }
    let haystack: String = lines.iter().map(|l| compact(l)).collect();
    let allowed = needle.chars().count() / CHARS_PER_EDIT;
    substring_distance(&needle, &haystack) <= allowed
}

/// Text recall and OCR time on one folder.
#[derive(Debug, Clone, Serialize)]
pub struct FolderResult {
    /// The folder as given, or `all` for the total.
    pub dataset: String,
    /// Frames read.
    pub frames: usize,
    /// Frames with at least one distinctive sign in view.
    pub frames_with_sign: usize,
    /// Those where OCR read at least one of the signs in view.
    pub frames_read: usize,
    /// Sign sightings: (sign, frame) pairs with the sign in view.
    pub sightings: usize,
    /// Those sightings where OCR read the sign.
    pub sightings_read: usize,
    /// Mean OCR time per image (detection and recognition), ms.
    pub ocr_ms: f64,
    /// Mean time of the whole extraction per image, ms.
    pub extract_ms: f64,
    /// Frames whose objects and text were carried over from an earlier
    /// frame (`perception.reuse`) instead of read.
    pub carried: usize,
}

impl FolderResult {
    fn recall(&self) -> f64 {
        ratio(self.frames_read, self.frames_with_sign)
    }
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

/// The image folder a data set's queries come from: `sequence` or `query`.
fn query_folder(dataset: &Path) -> anyhow::Result<&'static str> {
    for name in ["sequence", "query"] {
        if dataset.join(name).is_dir() {
            return Ok(name);
        }
    }
    bail!("{}: no sequence/ or query/ folder", dataset.display())
}

fn load_camera(path: &Path) -> anyhow::Result<Pinhole> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("reading {}", path.display()))
}

/// Counts visible pixels per instance id.
fn visible_pixels(mask: &annotations::InstanceMask) -> BTreeMap<u16, u32> {
    let mut counts = BTreeMap::new();
    for p in mask.pixels() {
        *counts.entry(p.0[0]).or_insert(0) += 1;
    }
    counts
}

async fn folder(
    perception: &Perception,
    dataset: &Path,
    frames: Option<std::ops::Range<usize>>,
    stride: usize,
    params: &VprParams,
) -> anyhow::Result<FolderResult> {
    let name = query_folder(dataset)?;
    let images = image_paths(&dataset.join(name))?;
    let poses = truth::load_tum(&dataset.join(format!("{name}_poses.txt")))?;
    if poses.len() != images.len() {
        bail!(
            "{}: {} poses for {} images",
            dataset.display(),
            poses.len(),
            images.len()
        );
    }
    let camera = load_camera(&dataset.join(format!("{name}_calib.json")))?;
    let frames = frames.unwrap_or(0..images.len());
    let selected: Vec<(&PathBuf, &Pose)> = images
        .iter()
        .zip(poses.iter().map(|(_, pose)| pose))
        .enumerate()
        .filter(|(i, _)| frames.contains(i) && (i - frames.start).is_multiple_of(stride))
        .map(|(_, frame)| frame)
        .collect();
    if selected.is_empty() {
        bail!(
            "{}: no frames in {frames:?} (it has {})",
            dataset.display(),
            images.len()
        );
    }
    let signs = signs(&Catalog::find(dataset)?, params);
    let mut result = FolderResult {
        dataset: dataset.display().to_string(),
        frames: selected.len(),
        frames_with_sign: 0,
        frames_read: 0,
        sightings: 0,
        sightings_read: 0,
        ocr_ms: 0.0,
        extract_ms: 0.0,
        carried: 0,
    };
    let bar = super::progress::progress(selected.len(), &result.dataset);
    for (path, pose) in selected {
        bar.inc(1);
        let mut seen: Vec<&Sign> = signs
            .iter()
            .filter(|s| in_view(&s.position, pose, &camera))
            .collect();
        if annotations::mask_path(path).is_some_and(|p| p.is_file()) {
            let pixels = visible_pixels(&annotations::read_mask(path)?);
            seen.retain(|s| pixels.get(&s.id).copied().unwrap_or(0) >= MIN_VISIBLE_PIXELS);
        }
        let data = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let started = Instant::now();
        let extracted = perception
            .extract_in(ImageInput::file(data), Some(&result.dataset))
            .await
            .with_context(|| format!("perceiving {}", path.display()))?;
        result.extract_ms += started.elapsed().as_secs_f64() * 1e3;
        result.carried += usize::from(extracted.objects_carried);
        result.ocr_ms += extracted
            .timings
            .iter()
            .filter(|(stage, _)| stage.starts_with("ocr"))
            .map(|(_, took)| took.as_secs_f64() * 1e3)
            .sum::<f64>();
        let lines: Vec<String> = extracted
            .features
            .objects
            .iter()
            .flat_map(|o| o.texts.iter().map(|t| t.text.clone()))
            .collect();
        tracing::debug!(image = %path.display(), ?lines, signs = ?seen.iter().map(|s| &s.text).collect::<Vec<_>>(), "read");
        if seen.is_empty() {
            continue;
        }
        result.frames_with_sign += 1;
        let read = seen
            .iter()
            .filter(|s| approximate_occurrence(&s.text, &lines))
            .count();
        result.sightings += seen.len();
        result.sightings_read += read;
        if read > 0 {
            result.frames_read += 1;
        }
    }
    bar.finish_and_clear();
    result.ocr_ms /= result.frames.max(1) as f64;
    result.extract_ms /= result.frames.max(1) as f64;
    Ok(result)
}

/// Runs `humem text-recall`.
pub async fn run(config: Config, args: TextRecallArgs) -> anyhow::Result<()> {
    if config.perception.ocr.is_none() {
        bail!("perception.ocr is off: there is no OCR to measure");
    }
    let perception_config = config.perception.clone();
    let top_k = config.store.scene_top_k;
    let perception =
        tokio::task::spawn_blocking(move || Perception::load(&perception_config, top_k))
            .await
            .context("loading the models")??;
    let mut results = Vec::new();
    for dataset in &args.dataset {
        results.push(
            folder(
                &perception,
                dataset,
                args.frames.clone(),
                args.stride as usize,
                &config.vpr,
            )
            .await?,
        );
    }
    let total = FolderResult {
        dataset: "all".into(),
        frames: results.iter().map(|r| r.frames).sum(),
        frames_with_sign: results.iter().map(|r| r.frames_with_sign).sum(),
        frames_read: results.iter().map(|r| r.frames_read).sum(),
        sightings: results.iter().map(|r| r.sightings).sum(),
        sightings_read: results.iter().map(|r| r.sightings_read).sum(),
        ocr_ms: weighted(&results, |r| r.ocr_ms),
        extract_ms: weighted(&results, |r| r.extract_ms),
        carried: results.iter().map(|r| r.carried).sum(),
    };
    println!(
        "{:<40} {:>7} {:>8} {:>10} {:>8} {:>8} {:>11} {:>8} {:>11}",
        "data set",
        "frames",
        "carried",
        "with sign",
        "read",
        "recall",
        "signs read",
        "OCR ms",
        "extract ms"
    );
    for r in results.iter().chain(std::iter::once(&total)) {
        println!(
            "{:<40} {:>7} {:>8} {:>10} {:>8} {:>8.3} {:>11} {:>8.1} {:>11.1}",
            r.dataset,
            r.frames,
            r.carried,
            r.frames_with_sign,
            r.frames_read,
            r.recall(),
            format!("{}/{}", r.sightings_read, r.sightings),
            r.ocr_ms,
            r.extract_ms
        );
    }
    if let Some(path) = &args.json {
        #[derive(Serialize)]
        struct Report<'a> {
            ocr: &'a Option<humem_perception::config::OcrConfig>,
            reuse: &'a humem_perception::reuse::ReuseConfig,
            stride: u32,
            folders: &'a [FolderResult],
            total: &'a FolderResult,
        }
        let report = Report {
            ocr: &config.perception.ocr,
            reuse: &config.perception.reuse,
            stride: args.stride,
            folders: &results,
            total: &total,
        };
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Mean of `value` over folders, weighted by their frames.
fn weighted(results: &[FolderResult], value: impl Fn(&FolderResult) -> f64) -> f64 {
    let frames: usize = results.iter().map(|r| r.frames).sum();
    results
        .iter()
        .map(|r| value(r) * r.frames as f64)
        .sum::<f64>()
        / frames.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    #[test]
    fn frame_ranges() {
        assert_eq!(parse_range("60..70"), Ok(60..70));
        assert!(parse_range("70..60").is_err());
        assert!(parse_range("60").is_err());
        assert!(parse_range("a..b").is_err());
    }

    #[test]
    fn substring_distance_by_hand() {
        assert_eq!(substring_distance("bakery", "acmebakery221"), 0);
        assert_eq!(substring_distance("bakery", "acmebakcry221"), 1);
        assert_eq!(substring_distance("bakery", "acmebakry"), 1);
        assert_eq!(substring_distance("abc", ""), 3);
        assert_eq!(substring_distance("", "abc"), 0);
    }

    #[test]
    fn signs_split_over_lines_or_merged_are_read() {
        let lines = |l: &[&str]| l.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert!(approximate_occurrence(
            "ACME BAKERY 221",
            &lines(&["ACME BAKERY", "221"])
        ));
        assert!(approximate_occurrence(
            "ACME BAKERY 221",
            &lines(&["OPEN ACME BAKERY 22l"])
        ));
        // Three slips in 13 characters are too many.
        assert!(!approximate_occurrence(
            "ACME BAKERY 221",
            &lines(&["ACNE BAKFRY 2Z1"])
        ));
        assert!(!approximate_occurrence(
            "ACME BAKERY 221",
            &lines(&["BAKERY"])
        ));
        assert!(!approximate_occurrence("ACME BAKERY 221", &[]));
    }

    #[test]
    fn distinctive_texts_name_places() {
        let params = VprParams::default();
        assert!(is_distinctive("ACME BAKERY 221", &params));
        assert!(is_distinctive("CEDAR AVE", &params));
        assert!(!is_distinctive("NO PARKING", &params));
        assert!(!is_distinctive("ONE WAY", &params));
        assert!(!is_distinctive("HOTEL", &params));
        assert!(!is_distinctive("30", &params));
    }

    #[test]
    fn in_view_by_hand() {
        // Camera at the origin looking along world +x (OpenCV z forward):
        // camera x = world −y, camera y = world −z, camera z = world x.
        let rotation = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            0.0, 0.0, 1.0, //
            -1.0, 0.0, 0.0, //
            0.0, -1.0, 0.0,
        ));
        let pose = Pose {
            t: Vector3::zeros(),
            r: UnitQuaternion::from_rotation_matrix(&rotation),
        };
        let camera = Pinhole {
            width: 512,
            height: 288,
            fx: 304.0,
            fy: 304.0,
            cx: 256.0,
            cy: 144.0,
        };
        assert!(in_view(&Vector3::new(10.0, 0.0, 0.0), &pose, &camera));
        // To the left at 45°: u = 256 − 304 < 0.
        assert!(!in_view(&Vector3::new(10.0, 10.0, 0.0), &pose, &camera));
        // Slightly left, up: inside.
        assert!(in_view(&Vector3::new(10.0, 3.0, 2.0), &pose, &camera));
        // Behind, and too far.
        assert!(!in_view(&Vector3::new(-10.0, 0.0, 0.0), &pose, &camera));
        assert!(!in_view(&Vector3::new(16.0, 0.0, 0.0), &pose, &camera));
    }
}
