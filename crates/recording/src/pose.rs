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

impl Pose {
    /// No motion: the frame itself.
    pub fn identity() -> Pose {
        Pose {
            t: Vector3::zeros(),
            r: UnitQuaternion::identity(),
        }
    }

    /// `self ∘ other`: `other` (a frame's pose in this pose's frame) in the
    /// frame this pose is given in.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            t: self.t + self.r * other.t,
            r: self.r * other.r,
        }
    }

    /// The pose a fraction `s` of the way from this one to `other`:
    /// position linearly, orientation by slerp.
    pub fn interpolate(&self, other: &Pose, s: f64) -> Pose {
        Pose {
            t: self.t.lerp(&other.t, s),
            r: self.r.slerp(&other.r, s),
        }
    }

    /// The inverse transform: this frame's parent seen from this frame.
    pub fn inverse(&self) -> Pose {
        let r = self.r.inverse();
        Pose {
            t: -(r * self.t),
            r,
        }
    }
}
