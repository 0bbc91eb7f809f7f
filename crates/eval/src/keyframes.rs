//! A data set image as an index stores it: keyframe `index` of a robot's
//! one session, at the origin, with the image's features.
//!
//! The in-process run and the verdict replay both fill real indexes the way
//! a SLAM client fills the service; they share this one shape (a leaf
//! module, so that neither has to import the other for it).

use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe};

/// Keyframe `index` of `robot`'s one session, as the index stores it.
pub(crate) fn stored(robot: &str, index: usize, features: &Features) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: robot.into(),
            session_id: String::new(),
            keyframe_id: index as u64,
        },
        frame_id: index as u64,
        timestamp: index as f64,
        map_id: 0,
        pose: Pose::default(),
        features: features.clone(),
    }
}
