//! Evaluation data sets on disk.
//!
//! Two shapes, as `../shared/datasets/README.md` describes them: `pairs`
//! (a `query/` folder matched against a `reference/` folder) and `loop` (one
//! `sequence/`, each frame a query against the earlier ones). Ground truth
//! comes from `ground_truth.json` when there is one, or else is computed
//! from poses beside the image folders (`<folder>_poses.txt` in TUM format,
//! or `<folder>_poses_kitti.txt`) with the paper's rule. Images are named by
//! their 0-based index.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use super::truth::{self, Kind, PoseRule};

/// A data set ready to evaluate.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The folder's name.
    pub name: String,
    /// Query/reference pairs, or one sequence searched against itself.
    pub kind: Kind,
    /// Query images (for `loop`, the sequence).
    pub queries: Vec<PathBuf>,
    /// Reference images (for `loop`, the same sequence).
    pub references: Vec<PathBuf>,
    /// Query index → indices of its valid matches.
    pub matches: BTreeMap<usize, Vec<usize>>,
    /// `loop` only: candidates must be at least this many frames earlier.
    pub min_frame_gap: usize,
    /// Where the ground truth came from, for the report.
    pub truth_source: String,
}

/// The JPEG and PNG images of a folder, sorted by name (their index).
pub fn image_paths(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    humem_perception::image::image_files(dir).with_context(|| format!("reading {}", dir.display()))
}

/// The `(timestamp, pose)` lines of an image folder's TUM pose file, if
/// one lies beside it.
fn tum_poses(dir: &Path, folder: &str) -> anyhow::Result<Option<Vec<(f64, truth::Pose)>>> {
    let tum = dir.join(format!("{folder}_poses.txt"));
    if !tum.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&tum)?;
    let poses = truth::parse_tum(&text).with_context(|| format!("parsing {}", tum.display()))?;
    Ok(Some(poses))
}

/// Poses of an image folder, if a pose file lies beside it.
pub fn poses(dir: &Path, folder: &str) -> anyhow::Result<Option<Vec<truth::Pose>>> {
    if let Some(poses) = tum_poses(dir, folder)? {
        return Ok(Some(poses.into_iter().map(|(_, p)| p).collect()));
    }
    let kitti = dir.join(format!("{folder}_poses_kitti.txt"));
    if kitti.is_file() {
        let text = std::fs::read_to_string(&kitti)?;
        return Ok(Some(
            truth::parse_kitti(&text).with_context(|| format!("parsing {}", kitti.display()))?,
        ));
    }
    Ok(None)
}

/// Timestamps of an image folder's frames, if a TUM pose file (whose
/// first column they are) lies beside it.
pub fn timestamps(dir: &Path, folder: &str) -> anyhow::Result<Option<Vec<f64>>> {
    Ok(tum_poses(dir, folder)?.map(|poses| poses.into_iter().map(|(t, _)| t).collect()))
}

impl Dataset {
    /// Reads the data set in `dir`. `rule` is used when the ground truth is
    /// computed from poses; `min_gap` overrides the file's frame gap.
    pub fn open(dir: &Path, rule: &PoseRule, min_gap: Option<usize>) -> anyhow::Result<Dataset> {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| dir.display().to_string());
        let gt_path = dir.join("ground_truth.json");
        let (kind, queries, references) = if dir.join("sequence").is_dir() {
            let seq = image_paths(&dir.join("sequence"))?;
            (Kind::Loop, seq.clone(), seq)
        } else if dir.join("query").is_dir() && dir.join("reference").is_dir() {
            (
                Kind::Pairs,
                image_paths(&dir.join("query"))?,
                image_paths(&dir.join("reference"))?,
            )
        } else {
            bail!(
                "{} has neither sequence/ (a loop data set) nor query/ and reference/ (a pairs data set)",
                dir.display()
            );
        };
        let (matches, file_gap, truth_source) = if gt_path.is_file() {
            let gt = truth::load_ground_truth(&gt_path)
                .with_context(|| format!("reading {}", gt_path.display()))?;
            if gt.kind != kind {
                bail!(
                    "{} says {:?} but the folders are a {:?} data set",
                    gt_path.display(),
                    gt.kind,
                    kind
                );
            }
            (
                gt.matches,
                gt.min_frame_gap,
                "ground_truth.json".to_string(),
            )
        } else {
            let matches = match kind {
                Kind::Loop => {
                    let poses = poses(dir, "sequence")?.with_context(|| {
                        format!(
                            "{} has no ground_truth.json and no sequence_poses.txt",
                            dir.display()
                        )
                    })?;
                    if poses.len() != queries.len() {
                        bail!("{} poses for {} images", poses.len(), queries.len());
                    }
                    truth::loop_truth(&poses, rule)
                }
                Kind::Pairs => {
                    let q = poses(dir, "query")?.with_context(|| {
                        format!(
                            "{} has no ground_truth.json and no query_poses.txt",
                            dir.display()
                        )
                    })?;
                    let r = poses(dir, "reference")?
                        .with_context(|| format!("{} has no reference_poses.txt", dir.display()))?;
                    truth::pairs_truth(&q, &r, rule)
                }
            };
            (
                matches,
                Some(rule.min_frame_gap),
                format!(
                    "poses: <= {} m, <= {} deg{}",
                    rule.max_distance_m,
                    rule.max_angle_deg,
                    if kind == Kind::Loop {
                        format!(", gap >= {}", rule.min_frame_gap)
                    } else {
                        String::new()
                    }
                ),
            )
        };
        for (&q, refs) in &matches {
            if q >= queries.len() || refs.iter().any(|&r| r >= references.len()) {
                bail!("ground truth names image {q} or its matches, beyond the images present");
            }
        }
        Ok(Dataset {
            name,
            kind,
            queries,
            references,
            matches,
            min_frame_gap: min_gap.or(file_gap).unwrap_or(100),
            truth_source,
        })
    }
}
