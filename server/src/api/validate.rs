//! Request validation: protobuf messages in, domain values out.
//!
//! Everything a client can get wrong is checked here, before any state is
//! touched, and reported with the path of the offending field
//! (`keyframes[3].features.objects[0].confidence: 1.5 is outside [0, 1]`),
//! so a client developer can fix the call from the message alone. What comes
//! out is normalised: unit descriptors and quaternions, scene classes sorted
//! and truncated to the configured top-k.

use std::collections::HashSet;

pub use crate::pipeline::request::{
    InvalidField, Observation, PendingKeyframe, QueryKind, QuerySpec,
};
use crate::proto;
use humem_core::keyframe::{
    Features, KeyframeKey, ObjectObservation, Pose, SceneClass, SessionKey, TextObservation,
};
use humem_core::vpr::eligibility::{MapRef, Scope};
use humem_core::vpr::params::Layers;
use humem_perception::ImageInput;
use humem_store::{PoseUpdate, RelativeTransform, Verdict, VerificationKind};

/// Largest descriptor accepted.
pub const MAX_DESCRIPTOR_LEN: usize = 8192;
/// Most scene classes accepted per keyframe.
pub const MAX_SCENE_CLASSES: usize = 64;
/// Most objects accepted per keyframe.
pub const MAX_OBJECTS: usize = 256;
/// Most OCR strings accepted per object.
pub const MAX_TEXTS: usize = 32;
/// Longest OCR string accepted, in characters.
pub const MAX_TEXT_CHARS: usize = 256;
/// Longest class name, in bytes.
pub const MAX_CLASS_BYTES: usize = 64;
/// Longest robot or session id, in bytes.
pub const MAX_ID_BYTES: usize = 128;
/// Most keyframes in one InsertBatch.
pub const MAX_BATCH: usize = 1024;
/// Most candidates a query may ask for.
pub const MAX_TOP_N: usize = 100;
/// Most ids in one Erase, and most updates in one UpdatePoses.
pub const MAX_IDS: usize = 100_000;
/// Most predecessor keyframe ids in one query.
pub const MAX_PREDECESSORS: usize = 16;
/// Most robot ids and maps, together, in a listed scope.
pub const MAX_LISTED: usize = 4096;

fn invalid(field: impl Into<String>, reason: impl Into<String>) -> InvalidField {
    InvalidField {
        field: field.into(),
        reason: reason.into(),
    }
}

type Result<T> = std::result::Result<T, InvalidField>;

/// Server-side settings validation depends on.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Scene classes kept per keyframe.
    pub scene_top_k: usize,
    /// Default minimum frame gap.
    pub min_frame_gap: u64,
    /// Default number of candidates.
    pub top_n: usize,
}

/// A robot id: required (non-empty), at most [`MAX_ID_BYTES`] bytes, no NUL.
pub fn robot_id(field: &str, id: &str) -> Result<String> {
    if id.is_empty() {
        return Err(invalid(field, "required"));
    }
    id_text(field, id)
}

fn id_text(field: &str, id: &str) -> Result<String> {
    if id.len() > MAX_ID_BYTES {
        return Err(invalid(field, format!("longer than {MAX_ID_BYTES} bytes")));
    }
    if id.contains('\0') {
        return Err(invalid(field, "contains a NUL character"));
    }
    Ok(id.to_string())
}

/// The (robot, session) of a request.
pub fn session(prefix: &str, robot: &str, session: &str) -> Result<SessionKey> {
    Ok(SessionKey {
        robot_id: robot_id(&format!("{prefix}robot_id"), robot)?,
        session_id: id_text(&format!("{prefix}session_id"), session)?,
    })
}

fn required<T>(field: &str, value: Option<T>) -> Result<T> {
    value.ok_or_else(|| invalid(field, "required"))
}

fn unit_interval(field: &str, value: f32) -> Result<f32> {
    if !value.is_finite() {
        return Err(invalid(field, "not a finite number"));
    }
    if !(0.0..=1.0).contains(&value) {
        return Err(invalid(field, format!("{value} is outside [0, 1]")));
    }
    Ok(value)
}

fn finite(field: &str, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(invalid(field, "not a finite number"))
    }
}

/// A pose, with its quaternion normalised.
pub fn pose(field: &str, pose: Option<&proto::Pose>) -> Result<Pose> {
    let pose = required(field, pose)?;
    let t = required(&format!("{field}.translation"), pose.translation.as_ref())?;
    let q = required(&format!("{field}.rotation"), pose.rotation.as_ref())?;
    let translation = [
        finite(&format!("{field}.translation.x"), t.x)?,
        finite(&format!("{field}.translation.y"), t.y)?,
        finite(&format!("{field}.translation.z"), t.z)?,
    ];
    let rotation = [
        finite(&format!("{field}.rotation.w"), q.w)?,
        finite(&format!("{field}.rotation.x"), q.x)?,
        finite(&format!("{field}.rotation.y"), q.y)?,
        finite(&format!("{field}.rotation.z"), q.z)?,
    ];
    let norm = rotation.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm > 1e-9 && norm.is_finite()) {
        return Err(invalid(
            format!("{field}.rotation"),
            "quaternion has zero length",
        ));
    }
    Ok(Pose {
        translation,
        rotation: rotation.map(|v| v / norm),
    })
}

/// Precomputed features, normalised.
pub fn features(field: &str, f: &proto::Features, limits: &Limits) -> Result<Features> {
    let descriptor = descriptor(&format!("{field}.global_descriptor"), &f.global_descriptor)?;
    let scene = scene(&format!("{field}.scene"), &f.scene, limits.scene_top_k)?;
    if f.objects.len() > MAX_OBJECTS {
        return Err(invalid(
            format!("{field}.objects"),
            format!("{} objects, at most {MAX_OBJECTS}", f.objects.len()),
        ));
    }
    let objects = f
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| object(&format!("{field}.objects[{i}]"), o))
        .collect::<Result<_>>()?;
    let appearance = appearance(&format!("{field}.appearance"), &f.appearance)?;
    Ok(Features {
        descriptor,
        scene,
        objects,
        appearance,
    })
}

/// A thumbnail's bytes as the signed values they encode.
fn appearance(field: &str, bytes: &[u8]) -> Result<Vec<i8>> {
    if !bytes.is_empty() && bytes.len() != humem_core::vpr::appearance::LEN {
        return Err(invalid(
            field,
            format!(
                "{} bytes, expected none or {} (64x48)",
                bytes.len(),
                humem_core::vpr::appearance::LEN
            ),
        ));
    }
    Ok(bytes.iter().map(|&b| b as i8).collect())
}

fn descriptor(field: &str, values: &[f32]) -> Result<Vec<f32>> {
    if values.is_empty() {
        return Err(invalid(field, "required (empty)"));
    }
    if values.len() > MAX_DESCRIPTOR_LEN {
        return Err(invalid(
            field,
            format!("{} values, at most {MAX_DESCRIPTOR_LEN}", values.len()),
        ));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(invalid(format!("{field}[{i}]"), "not a finite number"));
    }
    let norm = values
        .iter()
        .map(|&v| f64::from(v) * f64::from(v))
        .sum::<f64>()
        .sqrt();
    if norm < 1e-12 {
        return Err(invalid(field, "all values are zero"));
    }
    Ok(values
        .iter()
        .map(|&v| (f64::from(v) / norm) as f32)
        .collect())
}

fn scene(field: &str, classes: &[proto::SceneClass], top_k: usize) -> Result<Vec<SceneClass>> {
    if classes.len() > MAX_SCENE_CLASSES {
        return Err(invalid(
            field,
            format!("{} classes, at most {MAX_SCENE_CLASSES}", classes.len()),
        ));
    }
    let mut seen = HashSet::new();
    let mut total = 0.0f64;
    let mut out = Vec::with_capacity(classes.len());
    for (i, c) in classes.iter().enumerate() {
        let probability = unit_interval(&format!("{field}[{i}].probability"), c.probability)?;
        if !seen.insert(c.class_id) {
            return Err(invalid(
                format!("{field}[{i}].class_id"),
                format!("class {} appears twice", c.class_id),
            ));
        }
        total += f64::from(probability);
        out.push(SceneClass {
            class_id: c.class_id,
            probability,
        });
    }
    if total > 1.001 {
        return Err(invalid(
            field,
            format!("probabilities sum to {total:.4}, more than 1"),
        ));
    }
    out.sort_by(|a, b| {
        b.probability
            .total_cmp(&a.probability)
            .then(a.class_id.cmp(&b.class_id))
    });
    out.truncate(top_k);
    Ok(out)
}

fn object(field: &str, o: &proto::ObjectObservation) -> Result<ObjectObservation> {
    let class_field = format!("{field}.class_name");
    if o.class_name.is_empty() {
        return Err(invalid(class_field, "required"));
    }
    if o.class_name.len() > MAX_CLASS_BYTES {
        return Err(invalid(
            class_field,
            format!("longer than {MAX_CLASS_BYTES} bytes"),
        ));
    }
    if o.texts.len() > MAX_TEXTS {
        return Err(invalid(
            format!("{field}.texts"),
            format!("{} strings, at most {MAX_TEXTS}", o.texts.len()),
        ));
    }
    let texts = o
        .texts
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let f = format!("{field}.texts[{i}]");
            if t.text.trim().is_empty() {
                return Err(invalid(format!("{f}.text"), "empty"));
            }
            if t.text.chars().count() > MAX_TEXT_CHARS {
                return Err(invalid(
                    format!("{f}.text"),
                    format!("longer than {MAX_TEXT_CHARS} characters"),
                ));
            }
            Ok(TextObservation {
                text: t.text.clone(),
                confidence: unit_interval(&format!("{f}.confidence"), t.confidence)?,
            })
        })
        .collect::<Result<_>>()?;
    Ok(ObjectObservation {
        class_name: o.class_name.clone(),
        confidence: unit_interval(&format!("{field}.confidence"), o.confidence)?,
        centroid: [
            unit_interval(&format!("{field}.x"), o.x)?,
            unit_interval(&format!("{field}.y"), o.y)?,
        ],
        area: unit_interval(&format!("{field}.area"), o.area)?,
        texts,
    })
}

/// An image: the encoding is known and there are bytes; whether they decode
/// is found out by perception.
pub fn image(field: &str, image: proto::Image) -> Result<ImageInput> {
    use humem_perception::image::Encoding;
    use proto::image::Encoding as Wire;
    let encoding = match enumeration::<Wire>(&format!("{field}.encoding"), image.encoding)? {
        Wire::Unspecified => Encoding::Auto,
        Wire::Jpeg => Encoding::Jpeg,
        Wire::Png => Encoding::Png,
        Wire::Gray8 => Encoding::Gray8,
        Wire::Rgb8 => Encoding::Rgb8,
        Wire::Bgr8 => Encoding::Bgr8,
    };
    if image.data.is_empty() {
        return Err(invalid(format!("{field}.data"), "required (empty)"));
    }
    let raw = matches!(encoding, Encoding::Gray8 | Encoding::Rgb8 | Encoding::Bgr8);
    if raw && (image.width == 0 || image.height == 0) {
        return Err(invalid(
            format!("{field}.width"),
            "width and height are required for raw encodings",
        ));
    }
    Ok(ImageInput {
        encoding,
        data: image.data,
        width: image.width,
        height: image.height,
        stride: image.stride,
    })
}

fn observation(
    field: &str,
    features_or_image: Option<std::result::Result<proto::Features, proto::Image>>,
    limits: &Limits,
) -> Result<Option<Observation>> {
    Ok(match features_or_image {
        Some(Ok(f)) => Some(Observation::Features(features(
            &format!("{field}features"),
            &f,
            limits,
        )?)),
        Some(Err(img)) => {
            let image_field = format!("{field}image");
            Some(Observation::Image(image(&image_field, img)?, image_field))
        }
        None => None,
    })
}

/// A keyframe to store.
pub fn keyframe(
    field: &str,
    k: Option<proto::Keyframe>,
    limits: &Limits,
) -> Result<PendingKeyframe> {
    let k = required(field, k)?;
    let session = session(&format!("{field}."), &k.robot_id, &k.session_id)?;
    let keyframe_id = required(&format!("{field}.keyframe_id"), k.keyframe_id)?;
    let frame_id = required(&format!("{field}.frame_id"), k.frame_id)?;
    let timestamp = finite(&format!("{field}.timestamp"), k.timestamp)?;
    let map_id = required(&format!("{field}.map_id"), k.map_id)?;
    let pose = pose(&format!("{field}.pose"), k.pose.as_ref())?;
    let content = k.content.map(|c| match c {
        proto::keyframe::Content::Features(f) => Ok(f),
        proto::keyframe::Content::Image(i) => Err(i),
    });
    let observation = observation(&format!("{field}."), content, limits)?
        .ok_or_else(|| invalid(format!("{field}.features"), "required (or an image)"))?;
    Ok(PendingKeyframe {
        key: KeyframeKey {
            robot_id: session.robot_id,
            session_id: session.session_id,
            keyframe_id,
        },
        frame_id,
        timestamp,
        map_id,
        pose,
        observation,
    })
}

/// The keyframes of a batch; keys must be distinct.
pub fn batch(keyframes: Vec<proto::Keyframe>, limits: &Limits) -> Result<Vec<PendingKeyframe>> {
    if keyframes.is_empty() {
        return Err(invalid("keyframes", "required (empty)"));
    }
    if keyframes.len() > MAX_BATCH {
        return Err(invalid(
            "keyframes",
            format!("{} keyframes, at most {MAX_BATCH}", keyframes.len()),
        ));
    }
    let mut seen = HashSet::new();
    keyframes
        .into_iter()
        .enumerate()
        .map(|(i, k)| {
            let field = format!("keyframes[{i}]");
            let kf = keyframe(&field, Some(k), limits)?;
            if !seen.insert(kf.key.clone()) {
                return Err(invalid(
                    format!("{field}.keyframe_id"),
                    "the same keyframe appears twice in the batch",
                ));
            }
            Ok(kf)
        })
        .collect()
}

fn ids(field: &str, ids: &[u64], required_non_empty: bool) -> Result<Vec<u64>> {
    if required_non_empty && ids.is_empty() {
        return Err(invalid(field, "required (empty)"));
    }
    if ids.len() > MAX_IDS {
        return Err(invalid(
            field,
            format!("{} ids, at most {MAX_IDS}", ids.len()),
        ));
    }
    Ok(ids.to_vec())
}

/// Keyframe ids to erase.
pub fn erase(r: &proto::EraseRequest) -> Result<(SessionKey, Vec<u64>)> {
    Ok((
        session("", &r.robot_id, &r.session_id)?,
        ids("keyframe_ids", &r.keyframe_ids, true)?,
    ))
}

/// A verification verdict, as reported: everything but the receipt time,
/// which the server stamps (`reported_at` is 0 here).
pub fn verification(r: &proto::ReportVerificationRequest) -> Result<Verdict> {
    let session = session("", &r.robot_id, &r.session_id)?;
    let keyframe_id = required("keyframe_id", r.keyframe_id)?;
    let c = required("candidate", r.candidate.as_ref())?;
    let candidate = self::session("candidate.", &c.robot_id, &c.session_id)?
        .keyframe(required("candidate.keyframe_id", c.keyframe_id)?);
    let kind = match enumeration::<proto::VerificationKind>("kind", r.kind)? {
        proto::VerificationKind::Unspecified => return Err(invalid("kind", "required")),
        proto::VerificationKind::Loop => VerificationKind::Loop,
        proto::VerificationKind::Merge => VerificationKind::Merge,
        proto::VerificationKind::Relocalisation => VerificationKind::Relocalisation,
    };
    let accepted = match enumeration::<proto::VerificationOutcome>("outcome", r.outcome)? {
        proto::VerificationOutcome::Unspecified => return Err(invalid("outcome", "required")),
        proto::VerificationOutcome::Accepted => true,
        proto::VerificationOutcome::Rejected => false,
    };
    let query = session.keyframe(keyframe_id);
    if query == candidate {
        return Err(invalid("candidate", "is the query keyframe itself"));
    }
    let relative = match (&r.relative, accepted) {
        (Some(t), true) => {
            let scale = if t.scale == 0.0 {
                1.0
            } else {
                finite("relative.scale", t.scale)?
            };
            if scale <= 0.0 {
                return Err(invalid("relative.scale", format!("{scale} is not > 0")));
            }
            Some(RelativeTransform {
                pose: pose("relative.pose", t.pose.as_ref())?,
                scale,
            })
        }
        _ => None,
    };
    let score = r.score.map(|s| unit_interval("score", s)).transpose()?;
    Ok(Verdict {
        query,
        candidate,
        kind,
        accepted,
        relative,
        score,
        inliers: r.inliers,
        reported_at: 0.0,
    })
}

/// Pose updates.
pub fn pose_updates(r: &proto::UpdatePosesRequest) -> Result<(SessionKey, Vec<PoseUpdate>)> {
    let session = session("", &r.robot_id, &r.session_id)?;
    if r.updates.is_empty() {
        return Err(invalid("updates", "required (empty)"));
    }
    if r.updates.len() > MAX_IDS {
        return Err(invalid(
            "updates",
            format!("{} updates, at most {MAX_IDS}", r.updates.len()),
        ));
    }
    let mut seen = HashSet::new();
    let updates = r
        .updates
        .iter()
        .enumerate()
        .map(|(i, u)| {
            let field = format!("updates[{i}]");
            let id = required(&format!("{field}.keyframe_id"), u.keyframe_id)?;
            if !seen.insert(id) {
                return Err(invalid(
                    format!("{field}.keyframe_id"),
                    "keyframe updated twice",
                ));
            }
            Ok(PoseUpdate {
                keyframe_id: id,
                pose: pose(&format!("{field}.pose"), u.pose.as_ref())?,
                map_id: u.map_id,
            })
        })
        .collect::<Result<_>>()?;
    Ok((session, updates))
}

fn enumeration<E: TryFrom<i32>>(field: &str, value: i32) -> Result<E> {
    E::try_from(value).map_err(|_| invalid(field, format!("unknown value {value}")))
}

/// The query's scope; robot ids and maps are listed only with
/// `SCOPE_LISTED`.
fn scope(r: &proto::QueryRequest) -> Result<Scope> {
    let scope = match enumeration::<proto::Scope>("scope", r.scope)? {
        proto::Scope::Unspecified | proto::Scope::AllMaps => Scope::AllMaps,
        proto::Scope::SameMap => Scope::SameMap,
        proto::Scope::OtherMaps => Scope::OtherMaps,
        proto::Scope::Listed => listed(r)?,
    };
    if !r.robot_ids.is_empty() && !matches!(scope, Scope::Listed { .. }) {
        return Err(invalid("robot_ids", "only meaningful with SCOPE_LISTED"));
    }
    if !r.maps.is_empty() && !matches!(scope, Scope::Listed { .. }) {
        return Err(invalid("maps", "only meaningful with SCOPE_LISTED"));
    }
    Ok(scope)
}

/// A `SCOPE_LISTED` scope: the robots and maps listed, each checked.
fn listed(r: &proto::QueryRequest) -> Result<Scope> {
    if r.robot_ids.is_empty() && r.maps.is_empty() {
        return Err(invalid("scope", "SCOPE_LISTED needs robot_ids or maps"));
    }
    if r.robot_ids.len() + r.maps.len() > MAX_LISTED {
        return Err(invalid(
            "maps",
            format!("more than {MAX_LISTED} entries listed"),
        ));
    }
    let robot_ids = r
        .robot_ids
        .iter()
        .enumerate()
        .map(|(i, id)| robot_id(&format!("robot_ids[{i}]"), id))
        .collect::<Result<_>>()?;
    let maps = r
        .maps
        .iter()
        .enumerate()
        .map(|(i, m)| {
            Ok(MapRef {
                robot_id: robot_id(&format!("maps[{i}].robot_id"), &m.robot_id)?,
                session_id: m
                    .session_id
                    .as_deref()
                    .map(|s| id_text(&format!("maps[{i}].session_id"), s))
                    .transpose()?,
                map_id: m.map_id,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Scope::Listed { robot_ids, maps })
}

/// A query.
pub fn query(mut r: proto::QueryRequest, limits: &Limits) -> Result<QuerySpec> {
    let session = session("", &r.robot_id, &r.session_id)?;
    let content = r.content.take().map(|c| match c {
        proto::query_request::Content::Features(f) => Ok(f),
        proto::query_request::Content::Image(i) => Err(i),
    });
    let observation = observation("", content, limits)?;
    if observation.is_none() && r.keyframe_id.is_none() {
        return Err(invalid(
            "features",
            "required unless keyframe_id names a stored keyframe",
        ));
    }
    if observation.is_some() && r.frame_id.is_none() && r.keyframe_id.is_none() {
        return Err(invalid("frame_id", "required"));
    }
    if r.predecessor_keyframe_ids.len() > MAX_PREDECESSORS {
        return Err(invalid(
            "predecessor_keyframe_ids",
            format!(
                "{} ids, at most {MAX_PREDECESSORS}",
                r.predecessor_keyframe_ids.len()
            ),
        ));
    }
    let scope = scope(&r)?;
    let layers = match enumeration::<proto::Layers>("layers", r.layers)? {
        proto::Layers::Unspecified | proto::Layers::Full => Layers::FULL,
        proto::Layers::Scal => Layers::SCAL,
        proto::Layers::ScalOsrl => Layers::SCAL_OSRL,
        proto::Layers::ScalOgtl => Layers::SCAL_OGTL,
        proto::Layers::FullSupportOnly => Layers::FULL_SUPPORT_ONLY,
    };
    let kind = match enumeration::<proto::QueryKind>("kind", r.kind)? {
        proto::QueryKind::Unspecified | proto::QueryKind::LoopClosure => QueryKind::LoopClosure,
        proto::QueryKind::Relocalisation => QueryKind::Relocalisation,
    };
    let top_n = match r.top_n {
        None => limits.top_n,
        Some(0) => return Err(invalid("top_n", "must be at least 1")),
        Some(n) if n as usize > MAX_TOP_N => {
            return Err(invalid("top_n", format!("{n} is more than {MAX_TOP_N}")))
        }
        Some(n) => n as usize,
    };
    let threshold = r
        .threshold
        .map(|t| unit_interval("threshold", t))
        .transpose()?;
    Ok(QuerySpec {
        session,
        map_id: r.map_id,
        frame_id: r.frame_id,
        keyframe_id: r.keyframe_id,
        observation,
        predecessor_ids: r.predecessor_keyframe_ids.clone(),
        scope,
        readable_robots: None,
        min_frame_gap: r.min_frame_gap.unwrap_or(limits.min_frame_gap),
        top_n,
        threshold,
        layers,
        kind,
        exact: r.exact,
    })
}

#[cfg(test)]
pub(crate) mod tests;
