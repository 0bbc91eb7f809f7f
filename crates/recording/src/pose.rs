//! A camera pose, alone and at a time: what every reader gives and the
//! aligner interpolates.
//!
//! A leaf module of plain data, so that the readers ([`crate::bag`],
//! [`crate::layouts`], [`crate::messages`]), the aligner and the writer
//! share it without going through the crate root.

use nalgebra::{UnitQuaternion, Vector3};

/// A camera pose: position and orientation in the recording's world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position, metres.
    pub t: Vector3<f64>,
    /// Orientation.
    pub r: UnitQuaternion<f64>,
}

/// A pose at a time (seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedPose {
    /// Seconds.
    pub time: f64,
    /// The pose then.
    pub pose: Pose,
}
