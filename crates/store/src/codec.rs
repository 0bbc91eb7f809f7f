//! The on-disk format of the store: how keys and keyframe records are laid
//! out in sled.
//!
//! Keys sort by robot, session and keyframe id, so that a session is one
//! contiguous key range (a full reset is a range scan) and keyframes of a
//! session come back in id order. Values are a one-byte format version
//! followed by the record in postcard. postcard is compact and fast but not
//! self-describing, so any change to the persisted types must bump
//! [`FORMAT_VERSION`] and keep a decoder for the old one; the golden-bytes
//! test below fails on any accidental change of the layout.

use humem_core::keyframe::{KeyframeKey, SemanticKeyframe, SessionKey};
use humem_core::verdict::Verdict;

/// Version of the record layout written by this build. Version 2 added the
/// appearance thumbnail as the last field of the features, which are the
/// last field of a record.
pub const FORMAT_VERSION: u8 = 2;

/// Errors of decoding stored bytes.
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    /// The record's version byte is neither [`FORMAT_VERSION`] nor an
    /// older version this build still reads.
    #[error("stored record has format version {found}, this build reads version {FORMAT_VERSION}")]
    UnsupportedVersion {
        /// The version byte the record starts with.
        found: u8,
    },
    /// The record has no bytes, not even a version byte.
    #[error("stored record is empty")]
    Empty,
    /// The key is not `robot \0 session \0 keyframe_id`; says what is wrong.
    #[error("stored key is malformed: {0}")]
    BadKey(&'static str),
    /// The record body is not a valid postcard encoding of a keyframe.
    #[error("stored record does not decode: {0}")]
    Postcard(#[from] postcard::Error),
}

/// Separator between the string components of a key. Ids are validated to
/// contain no NUL byte, so the encoding is unambiguous and order-preserving.
const SEP: u8 = 0;

/// Key prefix of every keyframe of one session.
pub fn session_prefix(session: &SessionKey) -> Vec<u8> {
    let mut key = Vec::with_capacity(session.robot_id.len() + session.session_id.len() + 2);
    key.extend_from_slice(session.robot_id.as_bytes());
    key.push(SEP);
    key.extend_from_slice(session.session_id.as_bytes());
    key.push(SEP);
    key
}

/// The sled key of a keyframe: `robot \0 session \0 keyframe_id (big-endian)`.
pub fn encode_key(key: &KeyframeKey) -> Vec<u8> {
    let mut bytes = session_prefix(&key.session());
    bytes.extend_from_slice(&key.keyframe_id.to_be_bytes());
    bytes
}

/// Inverse of [`encode_key`].
pub fn decode_key(bytes: &[u8]) -> Result<KeyframeKey, CodecError> {
    if bytes.len() < 10 {
        return Err(CodecError::BadKey("too short"));
    }
    let (head, id) = bytes.split_at(bytes.len() - 8);
    let head = head
        .strip_suffix(&[SEP])
        .ok_or(CodecError::BadKey("missing separator"))?;
    let split = head
        .iter()
        .position(|&b| b == SEP)
        .ok_or(CodecError::BadKey("missing separator"))?;
    let text =
        |b: &[u8]| String::from_utf8(b.to_vec()).map_err(|_| CodecError::BadKey("not UTF-8"));
    Ok(KeyframeKey {
        robot_id: text(&head[..split])?,
        session_id: text(&head[split + 1..])?,
        keyframe_id: u64::from_be_bytes(id.try_into().expect("8 bytes")),
    })
}

/// Serialises a keyframe record with its format version.
pub fn encode_record(record: &SemanticKeyframe) -> Vec<u8> {
    let bytes = vec![FORMAT_VERSION];
    postcard::to_extend(record, bytes).expect("serialising to a Vec cannot fail")
}

/// Deserialises a record written by [`encode_record`].
pub fn decode_record(bytes: &[u8]) -> Result<SemanticKeyframe, CodecError> {
    match bytes.split_first() {
        None => Err(CodecError::Empty),
        Some((&FORMAT_VERSION, body)) => Ok(postcard::from_bytes(body)?),
        // Version 1 lacks only the trailing thumbnail: postcard writes an
        // empty `Vec` as one zero length byte.
        Some((&1, body)) => {
            let mut upgraded = Vec::with_capacity(body.len() + 1);
            upgraded.extend_from_slice(body);
            upgraded.push(0);
            Ok(postcard::from_bytes(&upgraded)?)
        }
        Some((&found, _)) => Err(CodecError::UnsupportedVersion { found }),
    }
}

/// Version of the verdict record layout written by this build.
pub const VERDICT_VERSION: u8 = 1;

/// The sled key of a verdict in the verdicts tree: the query's key, the
/// candidate's key, the kind's tag. Keyframe keys are self-delimiting
/// (`robot \0 session \0` and 8 bytes), so every verdict naming a query
/// keyframe is one prefix range.
pub fn verdict_key(verdict: &Verdict) -> Vec<u8> {
    let mut key = encode_key(&verdict.query);
    key.extend_from_slice(&encode_key(&verdict.candidate));
    key.push(verdict.kind.tag());
    key
}

/// The key of the same verdict in the by-candidate tree: the candidate's
/// key first, so every verdict naming a candidate is one prefix range.
pub fn verdict_candidate_key(verdict: &Verdict) -> Vec<u8> {
    let mut key = encode_key(&verdict.candidate);
    key.extend_from_slice(&encode_key(&verdict.query));
    key.push(verdict.kind.tag());
    key
}

/// The by-candidate key of the verdict whose verdicts-tree key is `key`,
/// whose query key is its first `query_len` bytes.
pub fn verdict_twin_key(key: &[u8], query_len: usize) -> Vec<u8> {
    let (query, rest) = key.split_at(query_len);
    let (candidate, kind) = rest.split_at(rest.len() - 1);
    let mut twin = Vec::with_capacity(key.len());
    twin.extend_from_slice(candidate);
    twin.extend_from_slice(query);
    twin.extend_from_slice(kind);
    twin
}

/// Serialises a verdict with its format version.
pub fn encode_verdict(verdict: &Verdict) -> Vec<u8> {
    postcard::to_extend(verdict, vec![VERDICT_VERSION]).expect("serialising to a Vec cannot fail")
}

/// Deserialises a verdict written by [`encode_verdict`].
pub fn decode_verdict(bytes: &[u8]) -> Result<Verdict, CodecError> {
    match bytes.split_first() {
        None => Err(CodecError::Empty),
        Some((&VERDICT_VERSION, body)) => Ok(postcard::from_bytes(body)?),
        Some((&found, _)) => Err(CodecError::UnsupportedVersion { found }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::keyframe::{Features, ObjectObservation, Pose, SceneClass, TextObservation};

    fn sample() -> SemanticKeyframe {
        SemanticKeyframe {
            key: KeyframeKey {
                robot_id: "r1".into(),
                session_id: "s".into(),
                keyframe_id: 258,
            },
            frame_id: 7,
            timestamp: 1.5,
            map_id: 2,
            pose: Pose {
                translation: [1.0, 0.0, -2.0],
                rotation: [1.0, 0.0, 0.0, 0.0],
            },
            features: Features {
                descriptor: vec![0.6, 0.8],
                scene: vec![SceneClass {
                    class_id: 3,
                    probability: 0.5,
                }],
                objects: vec![ObjectObservation {
                    class_name: "sign".into(),
                    confidence: 0.9,
                    centroid: [0.25, 0.5],
                    area: 0.125,
                    texts: vec![TextObservation {
                        text: "B-214".into(),
                        confidence: 1.0,
                    }],
                }],
                appearance: vec![-3, 0, 127],
            },
        }
    }

    #[test]
    fn key_round_trips_and_sorts_by_session_then_id() {
        let key = sample().key;
        assert_eq!(decode_key(&encode_key(&key)).unwrap(), key);
        let later = KeyframeKey {
            keyframe_id: 259,
            ..key.clone()
        };
        assert!(encode_key(&key) < encode_key(&later));
        assert!(encode_key(&key).starts_with(&session_prefix(&key.session())));
        let other_session = KeyframeKey {
            session_id: "s2".into(),
            ..key.clone()
        };
        assert!(!encode_key(&other_session).starts_with(&session_prefix(&key.session())));
    }

    #[test]
    fn record_round_trips() {
        let record = sample();
        assert_eq!(decode_record(&encode_record(&record)).unwrap(), record);
    }

    #[test]
    fn layout_is_pinned() {
        // If this fails, the on-disk format changed: bump FORMAT_VERSION and
        // keep a decoder for the older versions before updating these bytes.
        let hex: String = encode_record(&sample())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(hex, GOLDEN);
    }

    #[test]
    fn version_1_records_read_with_an_empty_thumbnail() {
        let bytes: Vec<u8> = (0..GOLDEN_V1.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&GOLDEN_V1[i..i + 2], 16).unwrap())
            .collect();
        let mut expected = sample();
        expected.features.appearance.clear();
        assert_eq!(decode_record(&bytes).unwrap(), expected);
    }

    const GOLDEN: &str = "020272310173820207000000000000f83f02000000000000f03f000000000000000000000000000000c0000000000000f03f000000000000000000000000000000000000000000000000029a99193fcdcc4c3f01030000003f01047369676e6666663f0000803e0000003f0000003e0105422d3231340000803f03fd007f";

    /// The sample, without its thumbnail, as version 1 wrote it.
    const GOLDEN_V1: &str = "010272310173820207000000000000f83f02000000000000f03f000000000000000000000000000000c0000000000000f03f000000000000000000000000000000000000000000000000029a99193fcdcc4c3f01030000003f01047369676e6666663f0000803e0000003f0000003e0105422d3231340000803f";

    #[test]
    fn other_versions_are_refused() {
        let mut bytes = encode_record(&sample());
        bytes[0] = 9;
        assert!(matches!(
            decode_record(&bytes),
            Err(CodecError::UnsupportedVersion { found: 9 })
        ));
        assert!(matches!(decode_record(&[]), Err(CodecError::Empty)));
    }
}
