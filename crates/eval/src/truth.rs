//! Ground truth for `humem eval`: read from a data set's `ground_truth.json`,
//! or computed from camera poses with the paper's rule.
//!
//! The rule (docs/evaluation.md, "the protocol"): a database frame `c` is a
//! valid match for query `q` when the camera positions are within 5 m, the
//! orientations within 30° (geodesic angle), and, for a single sequence
//! (`loop`), `c` is at least 100 frames earlier than `q`. The thresholds are
//! a [`PoseRule`] so that short sequences can use a smaller gap.
//!
//! Poses come in two text formats, both parsed here without touching the
//! file system so they can be tested on strings: TUM (`timestamp tx ty tz qx
//! qy qz qw`) and KITTI (a row-major 3×4 `[R|t]` per line). Rotations are
//! kept as unit quaternions; the KITTI matrices, printed with few digits, are
//! projected back onto the nearest rotation. Every bad line is reported with
//! its 1-based line number (and the file, through the `load_*` helpers);
//! nothing here panics on bad input.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Errors reading ground truth or poses.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    /// The file could not be read.
    #[error("reading {}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The read error.
        #[source]
        source: std::io::Error,
    },
    /// The ground-truth file is not JSON of the expected shape (the message
    /// of `serde_json` carries the line and column).
    #[error("{}: not a ground-truth file ({{\"kind\": \"pairs\"|\"loop\", \"matches\": {{...}}}}): {source}", .path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's error.
        #[source]
        source: serde_json::Error,
    },
    /// The ground-truth file parsed but its content is not valid.
    #[error("{}: {message}", .path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A line of a pose file could not be used.
    #[error("{}line {line}: {message}", origin(.path))]
    Pose {
        /// The file, when known (the `parse_*` functions work on text).
        path: Option<PathBuf>,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        message: String,
    },
}

fn origin(path: &Option<PathBuf>) -> String {
    match path {
        Some(p) => format!("{}: ", p.display()),
        None => String::new(),
    }
}

impl TruthError {
    /// Attaches the file a pose error came from.
    fn in_file(self, file: &Path) -> TruthError {
        match self {
            TruthError::Pose { line, message, .. } => TruthError::Pose {
                path: Some(file.to_path_buf()),
                line,
                message,
            },
            other => other,
        }
    }
}

/// Shape of a data set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// `query/` images matched against `reference/` images.
    Pairs,
    /// One `sequence/`; each frame is a query against the earlier frames.
    Loop,
}

/// The valid matches of each query of a data set.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruth {
    /// Query/reference pairs, or one sequence searched against itself.
    pub kind: Kind,
    /// `loop` only: candidates must be at least this many frames earlier.
    pub min_frame_gap: Option<usize>,
    /// Query index → sorted, distinct indices of its valid matches. Queries
    /// with no valid match are absent (they do not count).
    pub matches: BTreeMap<usize, Vec<usize>>,
}

/// `ground_truth.json` as written. Unknown fields are ignored so that data
/// sets may carry notes or provenance.
#[derive(Deserialize)]
struct RawGroundTruth {
    kind: Kind,
    matches: BTreeMap<String, Vec<usize>>,
    #[serde(default)]
    min_frame_gap: Option<usize>,
}

/// Reads a `ground_truth.json`:
/// `{"kind": "pairs"|"loop", "matches": {"<q>": [refs]}, "min_frame_gap": n?}`.
///
/// Query keys must be decimal indices. Match lists are sorted and
/// deduplicated; queries with an empty list are dropped, as the protocol
/// treats them like absent ones.
pub fn load_ground_truth(path: &Path) -> Result<GroundTruth, TruthError> {
    let text = std::fs::read_to_string(path).map_err(|source| TruthError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let raw: RawGroundTruth = serde_json::from_str(&text).map_err(|source| TruthError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    let mut matches = BTreeMap::new();
    for (key, mut refs) in raw.matches {
        let q: usize = key.trim().parse().map_err(|_| TruthError::Invalid {
            path: path.to_path_buf(),
            message: format!("query key {key:?} in \"matches\" is not a frame index"),
        })?;
        refs.sort_unstable();
        refs.dedup();
        if refs.is_empty() {
            continue;
        }
        if matches.insert(q, refs).is_some() {
            return Err(TruthError::Invalid {
                path: path.to_path_buf(),
                message: format!(
                    "query {q} is listed twice in \"matches\" (keys {key:?} and another spelling)"
                ),
            });
        }
    }
    Ok(GroundTruth {
        kind: raw.kind,
        min_frame_gap: raw.min_frame_gap,
        matches,
    })
}

/// A camera pose: position `t` and orientation `r` (as given by the file,
/// typically camera-to-world).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position, in the pose file's units (metres for TUM and KITTI).
    pub t: Vector3<f64>,
    /// Orientation, a unit quaternion.
    pub r: UnitQuaternion<f64>,
}

/// Splits a pose line into exactly `expected` finite numbers.
fn numbers(
    line: &str,
    line_no: usize,
    expected: usize,
    layout: &str,
) -> Result<Vec<f64>, TruthError> {
    let err = |message: String| TruthError::Pose {
        path: None,
        line: line_no,
        message,
    };
    let fields: Vec<&str> = line.split_whitespace().collect();
    if fields.len() != expected {
        return Err(err(format!(
            "expected {expected} numbers ({layout}), found {}",
            fields.len()
        )));
    }
    fields
        .iter()
        .enumerate()
        .map(|(i, f)| match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(err(format!("field {} is not finite: {f:?}", i + 1))),
            Err(_) => Err(err(format!("field {} is not a number: {f:?}", i + 1))),
        })
        .collect()
}

/// Lines that carry data: 1-based number and text, skipping blank lines and
/// `#` comments.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// Parses TUM poses: one `timestamp tx ty tz qx qy qz qw` per line, blank
/// lines and `#` comments skipped. The quaternion is normalised; a zero one
/// is rejected with its line number.
pub fn parse_tum(text: &str) -> Result<Vec<(f64, Pose)>, TruthError> {
    data_lines(text)
        .map(|(line_no, line)| {
            let v = numbers(line, line_no, 8, "timestamp tx ty tz qx qy qz qw")?;
            let q = nalgebra::Quaternion::new(v[7], v[4], v[5], v[6]);
            let norm = q.norm();
            if !norm.is_finite() || norm <= 1e-9 {
                return Err(TruthError::Pose {
                    path: None,
                    line: line_no,
                    message: format!(
                        "quaternion (qx qy qz qw) = ({} {} {} {}) has zero norm",
                        v[4], v[5], v[6], v[7]
                    ),
                });
            }
            let pose = Pose {
                t: Vector3::new(v[1], v[2], v[3]),
                r: UnitQuaternion::from_quaternion(q / norm),
            };
            Ok((v[0], pose))
        })
        .collect()
}

/// Largest Frobenius norm of `MᵀM − I` accepted for a KITTI rotation: the
/// files print ~6 significant digits (errors ~1e-6); anything near this
/// bound is not a rotation but a mistake (wrong column count, a scale).
const MAX_ORTHONORMALITY_ERROR: f64 = 0.05;

/// Parses KITTI poses: 12 numbers per line, the row-major 3×4 matrix
/// `[R|t]`. Blank lines and `#` comments are skipped. `R` is replaced by the
/// nearest rotation (the orthogonal polar factor, via SVD); a matrix that is
/// far from a rotation, or a reflection, is rejected with its line number.
pub fn parse_kitti(text: &str) -> Result<Vec<Pose>, TruthError> {
    data_lines(text)
        .map(|(line_no, line)| {
            let v = numbers(
                line,
                line_no,
                12,
                "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz",
            )?;
            let m = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            let r = nearest_rotation(&m).map_err(|message| TruthError::Pose {
                path: None,
                line: line_no,
                message,
            })?;
            Ok(Pose {
                t: Vector3::new(v[3], v[7], v[11]),
                r,
            })
        })
        .collect()
}

/// The rotation nearest to `m`, if `m` is close to one.
///
/// The orthogonal polar factor `UVᵀ` of the SVD is the rotation nearest in
/// the Frobenius norm, in closed form: unlike nalgebra's iterative
/// `Rotation3::from_matrix`, there is no convergence loop to bound on odd
/// input (the checks above already reject matrices far from a rotation).
fn nearest_rotation(m: &Matrix3<f64>) -> Result<UnitQuaternion<f64>, String> {
    let error = (m.transpose() * m - Matrix3::identity()).norm();
    if error.is_nan() || error > MAX_ORTHONORMALITY_ERROR {
        return Err(format!(
            "the 3x3 part is not a rotation (|RᵀR − I| = {error:.3})"
        ));
    }
    if m.determinant() <= 0.0 {
        return Err("the 3x3 part is a reflection (negative determinant)".to_string());
    }
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err("the 3x3 part could not be decomposed".to_string());
    };
    let r = u * v_t;
    Ok(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix_unchecked(r),
    ))
}

/// Reads a TUM pose file (see [`parse_tum`]); errors name the file.
pub fn load_tum(path: &Path) -> Result<Vec<(f64, Pose)>, TruthError> {
    let text = std::fs::read_to_string(path).map_err(|source| TruthError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_tum(&text).map_err(|e| e.in_file(path))
}

/// Reads a KITTI pose file (see [`parse_kitti`]); errors name the file.
pub fn load_kitti(path: &Path) -> Result<Vec<Pose>, TruthError> {
    let text = std::fs::read_to_string(path).map_err(|source| TruthError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_kitti(&text).map_err(|e| e.in_file(path))
}

/// Geodesic angle between two orientations, in degrees (the service's own
/// rule for views turned away uses the same function).
pub use humem_core::vpr::viewpoint::geodesic_deg;

/// The paper's thresholds for a valid match.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseRule {
    /// Largest distance between the camera positions, metres (inclusive).
    pub max_distance_m: f64,
    /// Largest geodesic angle between the orientations, degrees (inclusive).
    pub max_angle_deg: f64,
    /// `loop` only: a candidate must be at least this many frames earlier.
    pub min_frame_gap: usize,
}

impl Default for PoseRule {
    /// 5 m, 30°, 100 frames.
    fn default() -> Self {
        PoseRule {
            max_distance_m: 5.0,
            max_angle_deg: 30.0,
            min_frame_gap: 100,
        }
    }
}

impl PoseRule {
    /// Whether two poses are close enough in position and orientation
    /// (inclusive bounds; NaN never matches).
    fn close(&self, a: &Pose, b: &Pose) -> bool {
        (a.t - b.t).norm() <= self.max_distance_m && geodesic_deg(&a.r, &b.r) <= self.max_angle_deg
    }
}

/// Ground truth of one sequence: for each query `q`, the earlier frames `c`
/// with `q − c >= min_frame_gap` whose poses are close by `rule`. Queries
/// with no such frame are omitted.
pub fn loop_truth(poses: &[Pose], rule: &PoseRule) -> BTreeMap<usize, Vec<usize>> {
    let mut out = BTreeMap::new();
    for (q, query) in poses.iter().enumerate() {
        // Candidates 0..=q−gap; with gap 0 that includes q itself, which is
        // the literal reading of `q − c >= 0`.
        let Some(last) = q.checked_sub(rule.min_frame_gap) else {
            continue;
        };
        let refs: Vec<usize> = (0..=last)
            .filter(|&c| rule.close(query, &poses[c]))
            .collect();
        if !refs.is_empty() {
            out.insert(q, refs);
        }
    }
    out
}

/// Ground truth of a query set against a reference set: for each query, the
/// references whose poses are close by `rule` (no frame gap). Queries with
/// no such reference are omitted.
pub fn pairs_truth(
    queries: &[Pose],
    references: &[Pose],
    rule: &PoseRule,
) -> BTreeMap<usize, Vec<usize>> {
    queries
        .iter()
        .enumerate()
        .filter_map(|(q, query)| {
            let refs: Vec<usize> = references
                .iter()
                .enumerate()
                .filter(|(_, r)| rule.close(query, r))
                .map(|(c, _)| c)
                .collect();
            (!refs.is_empty()).then_some((q, refs))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    fn pose(x: f64, y: f64, yaw_deg: f64) -> Pose {
        Pose {
            t: Vector3::new(x, y, 0.0),
            r: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
        }
    }

    fn temp_file(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("humem-truth-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    /// `../shared/datasets` from the crate (the main crate and the scratch
    /// crate both sit two levels below the folder holding `shared`).
    fn datasets() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/datasets")
    }

    #[test]
    fn ground_truth_file_is_read() {
        let path = temp_file(
            "gt_loop.json",
            r#"{"kind": "loop", "min_frame_gap": 20, "note": "x",
                "matches": {"40": [2, 0, 1, 1], "41": [], "7": [3]}}"#,
        );
        let gt = load_ground_truth(&path).unwrap();
        assert_eq!(gt.kind, Kind::Loop);
        assert_eq!(gt.min_frame_gap, Some(20));
        assert_eq!(gt.matches.len(), 2);
        assert_eq!(gt.matches[&40], vec![0, 1, 2]);
        assert_eq!(gt.matches[&7], vec![3]);

        let path = temp_file(
            "gt_pairs.json",
            r#"{"kind": "pairs", "matches": {"0": [0, 1]}}"#,
        );
        let gt = load_ground_truth(&path).unwrap();
        assert_eq!(gt.kind, Kind::Pairs);
        assert_eq!(gt.min_frame_gap, None);
    }

    #[test]
    fn ground_truth_errors_name_the_file() {
        let missing = Path::new("/nonexistent/ground_truth.json");
        let e = load_ground_truth(missing).unwrap_err();
        assert!(matches!(e, TruthError::Io { .. }));
        assert!(
            e.to_string().contains("/nonexistent/ground_truth.json"),
            "{e}"
        );

        let bad_kind = temp_file("gt_bad_kind.json", r#"{"kind": "triples", "matches": {}}"#);
        let e = load_ground_truth(&bad_kind).unwrap_err();
        assert!(matches!(e, TruthError::Json { .. }));
        assert!(e.to_string().contains("gt_bad_kind.json"), "{e}");
        assert!(e.to_string().contains("line 1"), "{e}");

        let bad_key = temp_file(
            "gt_bad_key.json",
            r#"{"kind": "pairs", "matches": {"q1": [0]}}"#,
        );
        let e = load_ground_truth(&bad_key).unwrap_err();
        assert!(matches!(e, TruthError::Invalid { .. }));
        assert!(e.to_string().contains("\"q1\""), "{e}");

        let dup = temp_file(
            "gt_dup.json",
            r#"{"kind": "pairs", "matches": {"1": [0], "01": [2]}}"#,
        );
        assert!(matches!(
            load_ground_truth(&dup),
            Err(TruthError::Invalid { .. })
        ));

        let negative = temp_file(
            "gt_neg.json",
            r#"{"kind": "pairs", "matches": {"1": [-1]}}"#,
        );
        assert!(matches!(
            load_ground_truth(&negative),
            Err(TruthError::Json { .. })
        ));
    }

    #[test]
    fn tum_is_parsed_and_normalised() {
        let text = "# timestamp tx ty tz qx qy qz qw\n\n\
                    0.5 1 2 3 0 0 0 2\n  \
                    1.0 4 5 6 0 0 1 1  \n";
        let poses = parse_tum(text).unwrap();
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[0].0, 0.5);
        assert_eq!(poses[0].1.t, Vector3::new(1.0, 2.0, 3.0));
        assert!(geodesic_deg(&poses[0].1.r, &UnitQuaternion::identity()) < 1e-12);
        // (0, 0, 1, 1) normalised: 90° about z.
        assert!((geodesic_deg(&poses[1].1.r, &UnitQuaternion::identity()) - 90.0).abs() < 1e-9);
        let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), PI / 2.0);
        assert!(geodesic_deg(&poses[1].1.r, &expected) < 1e-9);
    }

    #[test]
    fn tum_errors_carry_the_line_number() {
        let zero = "# header\n0 0 0 0 0 0 0 1\n\n1 0 0 0 0 0 0 0\n";
        let e = parse_tum(zero).unwrap_err();
        match &e {
            TruthError::Pose { line, message, .. } => {
                assert_eq!(*line, 4);
                assert!(message.contains("zero norm"), "{message}");
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(e.to_string().starts_with("line 4:"), "{e}");

        let short = parse_tum("0 1 2 3 0 0 0\n").unwrap_err();
        assert!(matches!(short, TruthError::Pose { line: 1, .. }), "{short}");
        let text = parse_tum("0 1 2 x 0 0 0 1\n").unwrap_err();
        assert!(text.to_string().contains("field 4"), "{text}");
        let nan = parse_tum("0 1 2 NaN 0 0 0 1\n").unwrap_err();
        assert!(nan.to_string().contains("not finite"), "{nan}");
        assert!(parse_tum("").unwrap().is_empty());
    }

    #[test]
    fn load_tum_names_the_file() {
        let path = temp_file("bad_poses.txt", "0 0 0 0 0 0 0 1\n1 0 0\n");
        let e = load_tum(&path).unwrap_err();
        let text = e.to_string();
        assert!(text.contains("bad_poses.txt: line 2:"), "{text}");
        let ok = temp_file("good_poses.txt", "0 0 0 0 0 0 0 1\n");
        assert_eq!(load_tum(&ok).unwrap().len(), 1);
    }

    #[test]
    fn kitti_is_parsed_and_reorthonormalised() {
        // Identity, then 90° about z printed with KITTI-like precision
        // (slightly off an exact rotation), then 180° about x.
        let text = "1 0 0 1.5 0 1 0 -2 0 0 1 3\n\
                    # comment\n\
                    1.000000e-06 -9.999990e-01 0 10 9.999990e-01 1.0e-06 0 20 0 0 1.000001 30\n\
                    1 0 0 0 0 -1 0 0 0 0 -1 0\n";
        let poses = parse_kitti(text).unwrap();
        assert_eq!(poses.len(), 3);
        assert_eq!(poses[0].t, Vector3::new(1.5, -2.0, 3.0));
        assert!(geodesic_deg(&poses[0].r, &UnitQuaternion::identity()) < 1e-12);
        assert_eq!(poses[1].t, Vector3::new(10.0, 20.0, 30.0));
        let yaw90 = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), PI / 2.0);
        assert!(geodesic_deg(&poses[1].r, &yaw90) < 1e-3);
        // The stored rotation is a proper rotation again.
        let m = poses[1].r.to_rotation_matrix().into_inner();
        assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
        // 180° about x, where a quaternion's w is 0.
        let roll180 = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI);
        assert!(geodesic_deg(&poses[2].r, &roll180) < 1e-9);
        assert!((geodesic_deg(&poses[2].r, &UnitQuaternion::identity()) - 180.0).abs() < 1e-9);
    }

    #[test]
    fn kitti_rejects_non_rotations_with_the_line_number() {
        let scaled = "1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 2 0 0 0 0 2 0\n";
        let e = parse_kitti(scaled).unwrap_err();
        assert!(matches!(e, TruthError::Pose { line: 2, .. }), "{e}");
        assert!(e.to_string().contains("not a rotation"), "{e}");
        let mirror = "-1 0 0 0 0 1 0 0 0 0 1 0\n";
        let e = parse_kitti(mirror).unwrap_err();
        assert!(e.to_string().contains("reflection"), "{e}");
        let zeros = "0 0 0 0 0 0 0 0 0 0 0 0\n";
        assert!(parse_kitti(zeros).is_err());
        let short = parse_kitti("1 0 0 0 0 1 0 0 0 0 1\n").unwrap_err();
        assert!(short.to_string().contains("expected 12 numbers"), "{short}");
    }

    #[test]
    fn tum_and_kitti_of_the_same_rotation_agree() {
        let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        let reference = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.4);
        for angle in [0.1, 1.0, 2.5, PI - 1e-3] {
            let q = UnitQuaternion::from_axis_angle(&axis, angle);
            let tum = format!("0 1 2 3 {:.9} {:.9} {:.9} {:.9}\n", q.i, q.j, q.k, q.w);
            let m = q.to_rotation_matrix().into_inner();
            let kitti = format!(
                "{:.6e} {:.6e} {:.6e} 1 {:.6e} {:.6e} {:.6e} 2 {:.6e} {:.6e} {:.6e} 3\n",
                m[(0, 0)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 0)],
                m[(1, 1)],
                m[(1, 2)],
                m[(2, 0)],
                m[(2, 1)],
                m[(2, 2)]
            );
            let from_tum = parse_tum(&tum).unwrap()[0].1;
            let from_kitti = parse_kitti(&kitti).unwrap()[0];
            assert!(
                geodesic_deg(&from_tum.r, &from_kitti.r) < 1e-3,
                "angle {angle}"
            );
            let a = geodesic_deg(&reference, &from_tum.r);
            let b = geodesic_deg(&reference, &from_kitti.r);
            assert!((a - b).abs() < 1e-3, "angle {angle}: {a} vs {b}");
            assert_eq!(from_tum.t, from_kitti.t);
        }
    }

    #[test]
    fn geodesic_by_hand() {
        let id = UnitQuaternion::identity();
        let yaw = |d: f64| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f64::to_radians(d));
        assert!((geodesic_deg(&id, &yaw(30.0)) - 30.0).abs() < 1e-9);
        assert!((geodesic_deg(&yaw(10.0), &yaw(-25.0)) - 35.0).abs() < 1e-9);
        // 350° is 10° the other way round.
        assert!((geodesic_deg(&id, &yaw(350.0)) - 10.0).abs() < 1e-9);
        assert!((geodesic_deg(&id, &yaw(180.0)) - 180.0).abs() < 1e-9);
        // q and −q are the same rotation.
        let q = yaw(40.0);
        let neg = UnitQuaternion::new_unchecked(-q.into_inner());
        assert!(geodesic_deg(&q, &neg) < 1e-12);
        assert!((geodesic_deg(&id, &neg) - 40.0).abs() < 1e-9);
        // Tiny angles keep their precision.
        assert!((geodesic_deg(&id, &yaw(1e-6)) - 1e-6).abs() < 1e-15);
    }

    #[test]
    fn default_rule_is_the_papers() {
        let r = PoseRule::default();
        assert_eq!(
            (r.max_distance_m, r.max_angle_deg, r.min_frame_gap),
            (5.0, 30.0, 100)
        );
    }

    /// 201 frames standing still at the origin, then one query frame.
    fn trajectory_with_query(query: Pose) -> Vec<Pose> {
        let mut poses = vec![pose(0.0, 0.0, 0.0); 201];
        poses.push(query);
        poses
    }

    #[test]
    fn loop_rule_distance_boundary() {
        let rule = PoseRule::default();
        let near = loop_truth(&trajectory_with_query(pose(4.9, 0.0, 0.0)), &rule);
        // Query 201 matches frames 0..=101 (gap >= 100).
        assert_eq!(near[&201], (0..=101).collect::<Vec<_>>());
        let far = loop_truth(&trajectory_with_query(pose(5.1, 0.0, 0.0)), &rule);
        assert!(!far.contains_key(&201));
        // Exactly 5 m (3-4-5, exact in floating point) is inside.
        let exact = loop_truth(&trajectory_with_query(pose(3.0, 4.0, 0.0)), &rule);
        assert!(exact.contains_key(&201));
    }

    #[test]
    fn loop_rule_angle_boundary() {
        let rule = PoseRule::default();
        let within = loop_truth(&trajectory_with_query(pose(0.0, 0.0, 29.0)), &rule);
        assert_eq!(within[&201].len(), 102);
        let beyond = loop_truth(&trajectory_with_query(pose(0.0, 0.0, 31.0)), &rule);
        assert!(!beyond.contains_key(&201));
        let beyond_neg = loop_truth(&trajectory_with_query(pose(0.0, 0.0, -31.0)), &rule);
        assert!(!beyond_neg.contains_key(&201));
        // A tilt counts as well as a yaw.
        let mut tilted = pose(0.0, 0.0, 0.0);
        tilted.r = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 31f64.to_radians());
        assert!(!loop_truth(&trajectory_with_query(tilted), &rule).contains_key(&201));
    }

    #[test]
    fn loop_rule_gap_boundary() {
        // Frames walk away along x at 10 m a step except frame 0 and the
        // last, which sit at the origin: only their pairing can match.
        let make = |len: usize| -> Vec<Pose> {
            (0..len)
                .map(|i| {
                    if i == 0 || i == len - 1 {
                        pose(0.0, 0.0, 0.0)
                    } else {
                        pose(10.0 * i as f64, 0.0, 0.0)
                    }
                })
                .collect()
        };
        let rule = PoseRule::default();
        // Last index 99: gap 99 < 100, no match.
        assert!(loop_truth(&make(100), &rule).is_empty());
        // Last index 100: gap 100, matches frame 0.
        let m = loop_truth(&make(101), &rule);
        assert_eq!(m.len(), 1);
        assert_eq!(m[&100], vec![0]);
        // Only earlier frames: frame 0 is never a query with a match.
        assert!(!m.contains_key(&0));
    }

    #[test]
    fn loop_truth_on_a_revisit() {
        // Two passes along the same straight 50 m street, 1 m a frame, with a
        // gap of 40: the second pass (frames 50..100) sees the first again.
        let lap: Vec<Pose> = (0..50).map(|i| pose(i as f64, 0.0, 0.0)).collect();
        let poses: Vec<Pose> = lap.iter().chain(&lap).copied().collect();
        let rule = PoseRule {
            min_frame_gap: 40,
            ..PoseRule::default()
        };
        let m = loop_truth(&poses, &rule);
        // Frames 40..50 are 40 frames after frames 0..10 but 30+ m away.
        assert_eq!(m.keys().next(), Some(&50));
        assert_eq!(m.len(), 50);
        // Frame 50 (x = 0): frames 0..=5, and frame 10 is the last allowed.
        assert_eq!(m[&50], vec![0, 1, 2, 3, 4, 5]);
        // Frame 60 (x = 10): first-pass frames within 5 m, i.e. 5..=15.
        assert_eq!(m[&60], (5..=15).collect::<Vec<_>>());
        // Frame 99 (x = 49): 44..=49; its own pass is nearer than 40 frames.
        assert_eq!(m[&99], (44..=49).collect::<Vec<_>>());
        for (&q, refs) in &m {
            assert!(refs.iter().all(|&c| q - c >= 40));
        }
    }

    #[test]
    fn pairs_truth_without_gap() {
        let queries = vec![
            pose(0.0, 0.0, 0.0),
            pose(100.0, 0.0, 0.0),
            pose(10.0, 0.0, 45.0),
        ];
        let references = vec![
            pose(4.9, 0.0, 0.0),
            pose(5.1, 0.0, 0.0),
            pose(0.0, 0.0, 29.0),
            pose(0.0, 0.0, 31.0),
            pose(10.0, 1.0, 20.0),
        ];
        let m = pairs_truth(&queries, &references, &PoseRule::default());
        assert_eq!(m.len(), 2);
        assert_eq!(m[&0], vec![0, 2]);
        assert!(!m.contains_key(&1));
        assert_eq!(m[&2], vec![4]);
        assert!(pairs_truth(&[], &references, &PoseRule::default()).is_empty());
        assert!(pairs_truth(&queries, &[], &PoseRule::default()).is_empty());
    }

    #[test]
    fn nan_poses_never_match() {
        let mut bad = pose(0.0, 0.0, 0.0);
        bad.t.x = f64::NAN;
        let m = pairs_truth(&[bad], &[pose(0.0, 0.0, 0.0)], &PoseRule::default());
        assert!(m.is_empty());
    }

    #[test]
    fn town_dev_loop_poses_agree_with_its_ground_truth() {
        let dir = datasets().join("town-dev/loop");
        let poses_path = dir.join("sequence_poses.txt");
        if !poses_path.is_file() {
            eprintln!("skipping: {} is absent", poses_path.display());
            return;
        }
        let poses: Vec<Pose> = load_tum(&poses_path)
            .unwrap()
            .into_iter()
            .map(|(_, p)| p)
            .collect();
        let images = std::fs::read_dir(dir.join("sequence"))
            .unwrap()
            .filter_map(Result::ok)
            .filter(|e| {
                let name = e.file_name().to_string_lossy().to_ascii_lowercase();
                name.ends_with(".jpg") || name.ends_with(".jpeg") || name.ends_with(".png")
            })
            .count();
        assert_eq!(poses.len(), images, "one pose per image");

        let computed = loop_truth(&poses, &PoseRule::default());
        assert!(!computed.is_empty());
        let gt = load_ground_truth(&dir.join("ground_truth.json")).unwrap();
        assert_eq!(gt.kind, Kind::Loop);
        let pairs =
            |m: &BTreeMap<usize, Vec<usize>>| -> std::collections::BTreeSet<(usize, usize)> {
                m.iter()
                    .flat_map(|(&q, refs)| refs.iter().map(move |&c| (q, c)))
                    .collect()
            };
        let (a, b) = (pairs(&computed), pairs(&gt.matches));
        let common = a.intersection(&b).count();
        eprintln!(
            "town-dev/loop: {} poses; computed {} queries / {} pairs, ground_truth.json \
             (gap {:?}) {} queries / {} pairs; {} pairs in common, {} only computed, {} only in file",
            poses.len(),
            computed.len(),
            a.len(),
            gt.min_frame_gap,
            gt.matches.len(),
            b.len(),
            common,
            a.len() - common,
            b.len() - common
        );
        if gt.min_frame_gap == Some(PoseRule::default().min_frame_gap) {
            assert_eq!(
                computed.keys().collect::<Vec<_>>(),
                gt.matches.keys().collect::<Vec<_>>()
            );
            // Borderline pairs may flip with the file's rounding; allow 1%.
            let differing = (a.len() - common) + (b.len() - common);
            assert!(
                differing * 100 <= b.len(),
                "{differing} differing pairs of {}",
                b.len()
            );
        }
    }

    proptest! {
        #[test]
        fn geodesic_is_a_symmetric_bounded_angle(
            ax in -1.0f64..1.0, ay in -1.0f64..1.0, az in 0.1f64..1.0, a in -7.0f64..7.0,
            bx in -1.0f64..1.0, by in 0.1f64..1.0, bz in -1.0f64..1.0, b in -7.0f64..7.0,
        ) {
            let qa = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(Vector3::new(ax, ay, az)), a);
            let qb = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(Vector3::new(bx, by, bz)), b);
            let d = geodesic_deg(&qa, &qb);
            prop_assert!((0.0..=180.0).contains(&d));
            prop_assert!((d - geodesic_deg(&qb, &qa)).abs() < 1e-9);
            prop_assert!(geodesic_deg(&qa, &qa) < 1e-6);
            // Agrees with the rotation matrices' angle.
            let ra = qa.to_rotation_matrix();
            let rb = qb.to_rotation_matrix();
            prop_assert!((d - ra.angle_to(&rb).to_degrees()).abs() < 1e-4);
        }

        #[test]
        fn parsers_never_panic(text in "[0-9eE .+\\-#\nxna]{0,200}") {
            let _ = parse_tum(&text);
            let _ = parse_kitti(&text);
        }
    }
}
