//! The ORB-SLAM3 plugin's sent log (`HuMem.SentLog`) read back as a
//! replay's steps (`humem eval --replay-verdicts --replay-trajectory`).
//!
//! The plugin writes one line per thing it sends, in the order it sends
//! them: every keyframe inserted with the pose ORB-SLAM3 estimated then,
//! every pose update after a loop correction, a merge or a global bundle
//! adjustment, every erase and reset, and every loop query. Replayed in
//! that order, the index holds each keyframe where SLAM had put it when
//! each query was asked, which a ground-truth pose, or a drift drawn at
//! random, cannot stand in for. Keyframes are matched to the data set's
//! images by timestamp, so the ground truth of the images judges the
//! candidates.
//!
//! ```text
//! insert KF FRAME MAP TIMESTAMP tx ty tz qx qy qz qw
//! pose KF MAP tx ty tz qx qy qz qw
//! erase KF
//! reset_map MAP
//! reset_session
//! query KF MAP
//! ```

use std::collections::HashMap;

use anyhow::{bail, Context};

use super::replay_steps::{Step, ROBOT};
use humem_core::keyframe::Pose;

/// One line of the sent log. `kf` is ORB-SLAM3's keyframe id (`mnId`),
/// `map` its atlas map id, `pose` the camera-to-world pose sent.
#[derive(Debug, Clone, PartialEq)]
pub enum Sent {
    /// A keyframe inserted, made from the frame taken at `timestamp`.
    #[allow(missing_docs)]
    Insert {
        kf: u64,
        map: u64,
        timestamp: f64,
        pose: Pose,
    },
    /// A keyframe moved to `pose` in `map`.
    #[allow(missing_docs)]
    Pose { kf: u64, map: u64, pose: Pose },
    /// A keyframe erased (culled, or its map reset).
    #[allow(missing_docs)]
    Erase { kf: u64 },
    /// Every keyframe of `map` erased.
    #[allow(missing_docs)]
    ResetMap { map: u64 },
    /// Every keyframe erased; ids start again.
    ResetSession,
    /// A loop query about a keyframe.
    #[allow(missing_docs)]
    Query { kf: u64 },
}

/// `tx ty tz qx qy qz qw` as a pose.
fn pose(fields: &[&str]) -> Result<Pose, String> {
    let v: Vec<f64> = fields
        .iter()
        .map(|f| f.parse::<f64>().map_err(|_| format!("{f:?} is no number")))
        .collect::<Result<_, _>>()?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        return Err("a pose is 7 finite numbers: tx ty tz qx qy qz qw".into());
    }
    Ok(Pose {
        translation: [v[0], v[1], v[2]],
        rotation: [v[6], v[3], v[4], v[5]],
    })
}

fn number(field: Option<&&str>) -> Result<u64, String> {
    let f = field.ok_or("a field is missing")?;
    f.parse().map_err(|_| format!("{f:?} is no id"))
}

/// One line's fields as what it says.
fn line(f: &[&str]) -> Result<Sent, String> {
    let timestamp = |f: &str| f.parse().map_err(|_| format!("{f:?} is no timestamp"));
    Ok(match (f[0], f.len()) {
        ("insert", 12) => Sent::Insert {
            kf: number(f.get(1))?,
            map: number(f.get(3))?,
            timestamp: timestamp(f[4])?,
            pose: pose(&f[5..])?,
        },
        ("pose", 10) => Sent::Pose {
            kf: number(f.get(1))?,
            map: number(f.get(2))?,
            pose: pose(&f[3..])?,
        },
        ("erase", 2) => Sent::Erase {
            kf: number(f.get(1))?,
        },
        ("reset_map", 2) => Sent::ResetMap {
            map: number(f.get(1))?,
        },
        ("reset_session", 1) => Sent::ResetSession,
        ("query", 3) => Sent::Query {
            kf: number(f.get(1))?,
        },
        ("insert" | "pose" | "erase" | "reset_map" | "reset_session" | "query", n) => {
            return Err(format!("{n} fields are not what {:?} has", f[0]))
        }
        (other, _) => return Err(format!("no line kind {other:?}")),
    })
}

/// Parses a sent log; `#` lines and blank lines are skipped.
pub fn parse(text: &str) -> anyhow::Result<Vec<Sent>> {
    let mut sent = Vec::new();
    for (n, text) in text.lines().enumerate() {
        let text = text.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = text.split_whitespace().collect();
        sent.push(line(&fields).map_err(|e| anyhow::anyhow!("line {}: {e}", n + 1))?);
    }
    Ok(sent)
}

/// Image indices by timestamp: the image taken within a millisecond of it.
struct Clock {
    /// `(timestamp, image index)`, by time.
    sorted: Vec<(f64, usize)>,
}

impl Clock {
    fn new(timestamps: &[f64]) -> Clock {
        let mut sorted: Vec<(f64, usize)> = timestamps.iter().copied().zip(0..).collect();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        Clock { sorted }
    }

    fn image(&self, t: f64) -> Option<usize> {
        let at = self.sorted.partition_point(|&(s, _)| s < t);
        [at.checked_sub(1), Some(at)]
            .into_iter()
            .flatten()
            .filter_map(|i| self.sorted.get(i))
            .filter(|(s, _)| (s - t).abs() <= 1e-3)
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .map(|&(_, i)| i)
    }
}

/// The steps that replay `sent` over a data set whose images were taken at
/// `timestamps`: each keyframe stored as its frame's image, moved, erased
/// and asked about as it was. A reset erases what it reset.
pub(crate) fn steps(sent: &[Sent], timestamps: &[f64]) -> anyhow::Result<Vec<Step>> {
    let clock = Clock::new(timestamps);
    // Keyframes held now, with their maps.
    let mut held: HashMap<u64, u64> = HashMap::new();
    let mut steps = Vec::with_capacity(sent.len());
    for line in sent {
        match *line {
            Sent::Insert {
                kf,
                map,
                timestamp,
                pose,
            } => {
                let Some(image) = clock.image(timestamp) else {
                    bail!("keyframe {kf}: no image of the data set was taken at {timestamp:.6} s");
                };
                held.insert(kf, map);
                steps.push(Step::Store {
                    robot: ROBOT,
                    id: kf,
                    image,
                    map,
                    pose,
                });
            }
            Sent::Pose { kf, map, pose } => {
                if let Some(m) = held.get_mut(&kf) {
                    *m = map;
                    steps.push(Step::Move { id: kf, map, pose });
                }
            }
            Sent::Erase { kf } => {
                if held.remove(&kf).is_some() {
                    steps.push(Step::Erase { id: kf });
                }
            }
            Sent::ResetMap { map } => {
                let mut gone: Vec<u64> = held
                    .iter()
                    .filter(|&(_, &m)| m == map)
                    .map(|(&kf, _)| kf)
                    .collect();
                gone.sort_unstable();
                for kf in gone {
                    held.remove(&kf);
                    steps.push(Step::Erase { id: kf });
                }
            }
            Sent::ResetSession => {
                let mut gone: Vec<u64> = held.drain().map(|(kf, _)| kf).collect();
                gone.sort_unstable();
                steps.extend(gone.into_iter().map(|id| Step::Erase { id }));
            }
            Sent::Query { kf } => {
                if held.contains_key(&kf) {
                    steps.push(Step::Ask { id: kf });
                }
            }
        }
    }
    Ok(steps)
}

/// Reads the sent log at `path` as steps over a data set whose images were
/// taken at `timestamps`.
pub(crate) fn read(path: &std::path::Path, timestamps: &[f64]) -> anyhow::Result<Vec<Step>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the sent log {}", path.display()))?;
    let sent = parse(&text).with_context(|| format!("parsing {}", path.display()))?;
    let steps =
        steps(&sent, timestamps).with_context(|| format!("replaying {}", path.display()))?;
    if !steps.iter().any(|s| matches!(s, Step::Ask { .. })) {
        bail!("{}: no loop query to replay", path.display());
    }
    Ok(steps)
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOG: &str = "\
# HuMem sent log
insert 0 0 0 10.000000 0 0 0 0 0 0 1
insert 1 3 0 10.300000 1.5 0 0 0 0 0.6 0.8
query 1 0
pose 0 2 0.25 0 0 0 0 0 1
insert 2 7 2 10.700000 2 0 0 0 0 0 1
erase 1
query 1 0
query 2 2
reset_map 2
insert 0 0 5 10.900000 0 0 0 0 0 0 1
reset_session
";

    #[test]
    fn a_sent_log_becomes_the_steps_it_recorded() {
        let sent = parse(LOG).unwrap();
        assert_eq!(sent.len(), 11);
        assert_eq!(
            sent[1],
            Sent::Insert {
                kf: 1,
                map: 0,
                timestamp: 10.3,
                pose: Pose {
                    translation: [1.5, 0.0, 0.0],
                    rotation: [0.8, 0.0, 0.0, 0.6],
                },
            }
        );
        // Images every 0.1 s from 10.0 s.
        let timestamps: Vec<f64> = (0..10).map(|i| 10.0 + i as f64 * 0.1).collect();
        let steps = steps(&sent, &timestamps).unwrap();
        let at = |x: f64| Pose {
            translation: [x, 0.0, 0.0],
            ..Pose::default()
        };
        let store = |id, image, map, pose| Step::Store {
            robot: ROBOT,
            id,
            image,
            map,
            pose,
        };
        assert_eq!(
            steps,
            vec![
                store(0, 0, 0, at(0.0)),
                store(1, 3, 0, sent_pose(&sent[1])),
                Step::Ask { id: 1 },
                Step::Move {
                    id: 0,
                    map: 2,
                    pose: at(0.25)
                },
                store(2, 7, 2, at(2.0)),
                Step::Erase { id: 1 },
                // The second query about keyframe 1 came after its erase.
                Step::Ask { id: 2 },
                // reset_map 2 erases keyframes 0 (moved there) and 2.
                Step::Erase { id: 0 },
                Step::Erase { id: 2 },
                // Ids start again after a reset: keyframe 0 is a new one.
                store(0, 9, 5, at(0.0)),
                Step::Erase { id: 0 },
            ]
        );
    }

    fn sent_pose(s: &Sent) -> Pose {
        match s {
            Sent::Insert { pose, .. } => *pose,
            _ => unreachable!(),
        }
    }

    #[test]
    fn a_bad_line_or_an_unknown_frame_names_itself() {
        let e = parse("insert 0 0 0 1.0 0 0 0 0 0 1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && e.contains("11 fields"), "{e}");
        let e = parse("erase x\n").unwrap_err().to_string();
        assert!(e.contains("\"x\" is no id"), "{e}");
        let e = parse("move 1\n").unwrap_err().to_string();
        assert!(e.contains("no line kind \"move\""), "{e}");
        let e = parse("pose 1 0 0 0 0 0 0 0 nan\n").unwrap_err().to_string();
        assert!(e.contains("7 finite numbers"), "{e}");
        let sent = parse("insert 4 9 0 12.5 0 0 0 0 0 0 1\n").unwrap();
        let e = steps(&sent, &[10.0, 10.1]).unwrap_err().to_string();
        assert!(e.contains("keyframe 4") && e.contains("12.500000"), "{e}");
    }
}
