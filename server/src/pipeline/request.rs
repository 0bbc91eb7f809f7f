//! The request domain: what a validated request asks for, in the
//! service's own types. The API layer produces these from protobuf
//! messages; the pipeline consumes them and never sees a protobuf type.

use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::params::Layers;
use humem_perception::ImageInput;

/// A request field that is wrong, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {reason}")]
pub struct InvalidField {
    /// Path of the offending field, e.g. `keyframes[3].features.objects[0]`.
    pub field: String,
    /// What is wrong with it, e.g. `1.5 is outside [0, 1]`.
    pub reason: String,
}

/// What a query is for; queries of different kinds never displace each
/// other in latest-wins, and metrics are labelled by kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum QueryKind {
    /// Loop closure or map merge for a new keyframe.
    LoopClosure,
    /// Relocalisation of a frame while tracking is lost.
    Relocalisation,
}

impl QueryKind {
    /// The kind's label in metrics.
    pub fn label(self) -> &'static str {
        match self {
            QueryKind::LoopClosure => "loop_closure",
            QueryKind::Relocalisation => "relocalisation",
        }
    }
}

/// A validated query.
#[derive(Debug, Clone)]
pub struct QuerySpec {
    /// The robot and session that ask.
    pub session: SessionKey,
    /// Map the querying frame is tracked in, if sent (else the stored
    /// keyframe's).
    pub map_id: Option<u64>,
    /// Source-frame id of the query, if sent (else the stored keyframe's).
    pub frame_id: Option<u64>,
    /// The query's keyframe id, when the query is a keyframe.
    pub keyframe_id: Option<u64>,
    /// What the query shows, if sent (else the stored keyframe's features).
    pub observation: Option<Observation>,
    /// Ids of the query's preceding keyframes in its session, most recent
    /// first; empty: the stored predecessors of `keyframe_id`.
    pub predecessor_ids: Vec<u64>,
    /// Which maps to search.
    pub scope: Scope,
    /// The robots whose maps the caller may read (access rules); `None`:
    /// every robot.
    pub readable_robots: Option<Vec<String>>,
    /// Least source-frame gap to keyframes of the querying session.
    pub min_frame_gap: u64,
    /// Most candidates returned, at least 1.
    pub top_n: usize,
    /// Candidates must score strictly above this, in [0, 1]; 0 keeps every
    /// ranked candidate; None: the store's operating point
    /// ([`humem_core::index::Index::operating_point`]).
    pub threshold: Option<f32>,
    /// The scoring layers used.
    pub layers: Layers,
    /// What the query is for.
    pub kind: QueryKind,
    /// Answer from a pass over every eligible keyframe, never from the
    /// neighbour graph's candidates.
    pub exact: bool,
}

/// What a keyframe or query shows, as sent.
#[derive(Debug, Clone)]
pub enum Observation {
    /// Ready-made features: as the client sent them, or already computed
    /// from its image.
    Features(Features),
    /// An image for the server's models, with the request field it came in
    /// (for error messages).
    Image(ImageInput, String),
}

/// A validated keyframe whose features may still have to be computed from
/// its image.
#[derive(Debug, Clone)]
pub struct PendingKeyframe {
    /// Robot, session and keyframe id.
    pub key: KeyframeKey,
    /// Source-frame id the keyframe was made from.
    pub frame_id: u64,
    /// Timestamp, in seconds.
    pub timestamp: f64,
    /// Atlas map id within the robot's session.
    pub map_id: u64,
    /// Camera pose in that map, its quaternion normalised.
    pub pose: Pose,
    /// Its features, or the image to compute them from.
    pub observation: Observation,
}

impl PendingKeyframe {
    /// The keyframe, with the features made of its observation.
    pub fn with_features(self, features: Features) -> SemanticKeyframe {
        SemanticKeyframe {
            key: self.key,
            frame_id: self.frame_id,
            timestamp: self.timestamp,
            map_id: self.map_id,
            pose: self.pose,
            features,
        }
    }
}
