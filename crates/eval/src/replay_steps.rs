//! What a replay sends, step by step: the keyframes stored, moved and
//! erased and the queries asked, in the order a SLAM client sends them.
//!
//! A leaf below [`verdict_replay`](super::verdict_replay), which runs the
//! steps, and [`sent_log`](super::sent_log), which reads a recorded
//! client's: a data set's own stream and a recording are one shape, so
//! one pass judges both.

use super::dataset::Dataset;
use super::truth::Kind;
use humem_core::keyframe::Pose;

/// Robot of the drive (a loop's frames, a pairs set's queries).
pub(crate) const ROBOT: &str = "drive";
/// Robot of a pairs set's references.
pub(crate) const REFERENCE_ROBOT: &str = "reference";

/// One step of a replay: what a SLAM client sends, in the order it sends
/// it. A data set's own stream stores every frame as keyframe `image` of
/// map 0 and asks about it ([`dataset_steps`]); a recorded trajectory
/// (`trajectory_replay`) also moves and erases keyframes, in maps of its
/// own.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Step {
    /// Stores image `image` of `robot` ([`ROBOT`] or [`REFERENCE_ROBOT`])
    /// as keyframe `id` of map `map` of its one session, at `pose`.
    Store {
        robot: &'static str,
        id: u64,
        image: usize,
        map: u64,
        pose: Pose,
    },
    /// Moves keyframe `id` of the drive to `pose` in map `map` (a pose
    /// update after a loop correction or a merge).
    Move { id: u64, map: u64, pose: Pose },
    /// Erases keyframe `id` of the drive.
    Erase { id: u64 },
    /// Asks about stored keyframe `id` of the drive.
    Ask { id: u64 },
}

/// A data set streamed as the plugin streams it: for pairs, the
/// references first, then each query frame stored and asked about; for a
/// loop, each frame stored and (once `gap` frames are stored) asked about.
/// Keyframe ids are image indices, all in map 0.
pub(crate) fn dataset_steps(
    dataset: &Dataset,
    (reference_poses, query_poses): &StreamPoses,
) -> Vec<Step> {
    let pairs = dataset.kind == Kind::Pairs;
    let store = |robot, i: usize, pose| Step::Store {
        robot,
        id: i as u64,
        image: i,
        map: 0,
        pose,
    };
    let mut steps = Vec::new();
    if pairs {
        for (i, &pose) in reference_poses.iter().enumerate() {
            steps.push(store(REFERENCE_ROBOT, i, pose));
        }
    }
    for (q, &pose) in query_poses.iter().enumerate() {
        steps.push(store(ROBOT, q, pose));
        if pairs || q >= dataset.min_frame_gap {
            steps.push(Step::Ask { id: q as u64 });
        }
    }
    steps
}

/// The poses a replay stores its frames at: `(references, queries)`.
pub type StreamPoses = (Vec<Pose>, Vec<Pose>);
