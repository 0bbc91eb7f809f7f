//! The semantic keyframe `K_i = (i, f_i, t_i, m_i, T_i, S_i, O_i)` of the
//! paper, plus its owner (robot and session), as plain data.
//!
//! These types are what every layer below the API speaks: `vpr/` scores them,
//! `store/` persists them, `api/` converts protobuf messages into them after
//! validation. They carry no gRPC or storage concerns, so that the scoring
//! can be tested and benchmarked on its own.

use serde::{Deserialize, Serialize};

/// Identity of a keyframe. ORB-SLAM3 keyframe ids are unique only within one
/// robot's run, and restart after a full reset, so the robot and the session
/// are part of the key.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct KeyframeKey {
    /// The robot that made the keyframe.
    pub robot_id: String,
    /// The robot's SLAM session; a new one starts after a full reset.
    pub session_id: String,
    /// Keyframe id, unique within one robot's session.
    pub keyframe_id: u64,
}

/// The stream a keyframe belongs to: one robot's one SLAM session.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct SessionKey {
    /// The robot that runs the session.
    pub robot_id: String,
    /// The session, unique within the robot.
    pub session_id: String,
}

impl SessionKey {
    /// The key of keyframe `keyframe_id` of this session.
    pub fn keyframe(&self, keyframe_id: u64) -> KeyframeKey {
        KeyframeKey {
            robot_id: self.robot_id.clone(),
            session_id: self.session_id.clone(),
            keyframe_id,
        }
    }
}

impl KeyframeKey {
    /// A 64-bit hash of the key (FNV-1a over robot, session and keyframe
    /// id), the same in every process, build and replica: what the
    /// neighbour graphs and the null model's sample name a keyframe by.
    pub fn stable_hash(&self) -> u64 {
        crate::numeric::fnv1a(&[
            self.robot_id.as_bytes(),
            self.session_id.as_bytes(),
            &self.keyframe_id.to_le_bytes(),
        ])
    }

    /// The session this keyframe belongs to.
    pub fn session(&self) -> SessionKey {
        SessionKey {
            robot_id: self.robot_id.clone(),
            session_id: self.session_id.clone(),
        }
    }

    /// Whether this keyframe belongs to `session` (same robot and session).
    pub fn in_session(&self, session: &SessionKey) -> bool {
        self.robot_id == session.robot_id && self.session_id == session.session_id
    }
}

/// Camera pose in its map: the camera-to-world transform `T_wc`
/// (ORB-SLAM3's `GetPoseInverse()`), rotation as a unit quaternion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Translation `(x, y, z)` in map units (metres for metric maps).
    pub translation: [f64; 3],
    /// Rotation quaternion `(w, x, y, z)`, unit length.
    pub rotation: [f64; 4],
}

impl Default for Pose {
    fn default() -> Self {
        Pose {
            translation: [0.0; 3],
            rotation: [1.0, 0.0, 0.0, 0.0],
        }
    }
}

/// One entry of a (truncated) scene-class distribution, e.g. Places365.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SceneClass {
    /// Index of the class in the scene classifier's label set.
    pub class_id: u32,
    /// Probability of the class, in [0, 1].
    pub probability: f32,
}

/// An OCR string read inside an object's region.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TextObservation {
    /// The string as read, before normalisation.
    pub text: String,
    /// Recogniser confidence `p_u` in [0, 1].
    pub confidence: f32,
}

/// A stable object seen in the keyframe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectObservation {
    /// Semantic class label, e.g. `building`, `sign`, `street_light`.
    pub class_name: String,
    /// Detector confidence `p` in [0, 1].
    pub confidence: f32,
    /// Centroid `(x, y)`, normalised to the image, each in [0, 1].
    pub centroid: [f32; 2],
    /// Area normalised by the image area, in [0, 1].
    pub area: f32,
    /// Text read on the object.
    pub texts: Vec<TextObservation>,
}

/// What perception extracts from one image: the global descriptor `e`, the
/// scene-class distribution `S`, the objects `O` and the appearance
/// thumbnail.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Features {
    /// Global descriptor, L2-normalised.
    pub descriptor: Vec<f32>,
    /// Top entries of the scene-class distribution, highest first.
    pub scene: Vec<SceneClass>,
    /// Stable objects detected in the image, with the text read on them.
    pub objects: Vec<ObjectObservation>,
    /// Appearance thumbnail ([`crate::vpr::appearance`]): the image in grey
    /// at 64×48, patch-normalised, as `i8`, row-major; empty when none.
    /// Last, so that records of format version 1 read as version 2 with an
    /// empty thumbnail (see `store::codec`).
    #[serde(default)]
    pub appearance: Vec<i8>,
}

/// A semantic keyframe as stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SemanticKeyframe {
    /// Identity `i`: robot, session and keyframe id.
    pub key: KeyframeKey,
    /// Source-frame id `f_i` (the frame the keyframe was made from).
    pub frame_id: u64,
    /// Timestamp `t_i` in seconds.
    pub timestamp: f64,
    /// Atlas map id `m_i` within the robot's session.
    pub map_id: u64,
    /// Camera pose `T_i` in map `m_i`.
    pub pose: Pose,
    /// What perception extracted from the keyframe's image: descriptor,
    /// scene `S_i`, objects `O_i` and appearance thumbnail.
    pub features: Features,
}
