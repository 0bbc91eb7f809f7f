//! The write log's entries: a store [`Mutation`] in postcard, with the
//! format version in a header.
//!
//! Every replica decodes every entry, so the format decides what mixed
//! versions can do during a rolling upgrade. The version travels in the
//! `Humem-Log-Format` header, not the payload, so a replica can tell an
//! entry from a newer build (it waits for its own upgrade, never skips it)
//! from an entry that is garbage in a format it knows (every replica
//! skips it alike, so they stay equal).

use humem_store::Mutation;

/// Header naming an entry's format version.
pub const FORMAT_HEADER: &str = "Humem-Log-Format";

/// The newest format this build reads. Format 2 added verdicts
/// (`Mutation::ReportVerdict`), format 3 inserts checked against a
/// keyframe quota (`Mutation::InsertWithin`); every other change is still
/// written as format 1 ([`format_of`]), so a replica of an older build
/// keeps applying them during a rolling upgrade and waits at the first
/// entry it cannot read instead of skipping it.
pub const FORMAT: u32 = 3;

/// The format an entry carrying `mutation` is written in: the oldest that
/// holds it.
pub fn format_of(mutation: &Mutation) -> u32 {
    match mutation {
        Mutation::ReportVerdict(_) => 2,
        Mutation::InsertWithin { .. } => 3,
        _ => 1,
    }
}

/// Why an entry cannot be applied.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EntryError {
    /// Written by a newer build: this replica must be upgraded to go on.
    #[error("log entry format {found} is newer than this build reads ({supported}); upgrade this replica")]
    Newer {
        /// The entry's format.
        found: u32,
        /// The newest this build reads.
        supported: u32,
    },
    /// Not a HuMem entry in a known format (no or bad header, or a payload
    /// that does not decode).
    #[error("not a HuMem log entry: {0}")]
    Garbage(String),
}

/// Encodes a change as an entry's payload (its header value is [`FORMAT`]).
pub fn encode(mutation: &Mutation) -> Vec<u8> {
    // Encoding owned, plain data into a Vec cannot fail.
    postcard::to_allocvec(mutation).expect("a mutation always encodes")
}

/// Decodes an entry from its format header value and payload.
pub fn decode(format: Option<&str>, payload: &[u8]) -> Result<Mutation, EntryError> {
    let format = format
        .ok_or_else(|| EntryError::Garbage(format!("no {FORMAT_HEADER} header")))?
        .parse::<u32>()
        .map_err(|_| EntryError::Garbage(format!("{FORMAT_HEADER} is not a number")))?;
    if format > FORMAT {
        return Err(EntryError::Newer {
            found: format,
            supported: FORMAT,
        });
    }
    postcard::from_bytes(payload).map_err(|e| EntryError::Garbage(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::keyframe::SessionKey;

    #[test]
    fn entries_round_trip_and_strangers_are_told_apart() {
        let mutation = Mutation::Erase {
            session: SessionKey {
                robot_id: "r".into(),
                session_id: "s".into(),
            },
            keyframe_ids: vec![1, 2],
        };
        let payload = encode(&mutation);
        assert_eq!(decode(Some("1"), &payload).unwrap(), mutation);
        assert_eq!(format_of(&mutation), 1);
        assert_eq!(decode(Some("2"), &payload).unwrap(), mutation);
        assert_eq!(
            decode(Some("4"), &payload).unwrap_err(),
            EntryError::Newer {
                found: 4,
                supported: 3
            }
        );
        let within = Mutation::InsertWithin {
            keyframes: Vec::new(),
            max_per_robot: 7,
        };
        assert_eq!(format_of(&within), 3);
        assert_eq!(decode(Some("3"), &encode(&within)).unwrap(), within);
        let verdict = Mutation::ReportVerdict(humem_core::verdict::Verdict {
            query: humem_core::keyframe::KeyframeKey {
                robot_id: "r".into(),
                session_id: "s".into(),
                keyframe_id: 2,
            },
            candidate: humem_core::keyframe::KeyframeKey {
                robot_id: "r".into(),
                session_id: "s".into(),
                keyframe_id: 1,
            },
            kind: humem_core::verdict::VerificationKind::Merge,
            accepted: true,
            relative: None,
            score: None,
            inliers: 12,
            reported_at: 5.0,
        });
        assert_eq!(format_of(&verdict), 2);
        assert_eq!(decode(Some("2"), &encode(&verdict)).unwrap(), verdict);
        assert!(matches!(
            decode(None, &payload),
            Err(EntryError::Garbage(_))
        ));
        assert!(matches!(
            decode(Some("one"), &payload),
            Err(EntryError::Garbage(_))
        ));
        assert!(matches!(
            decode(Some("1"), b"\xff\xff\xff"),
            Err(EntryError::Garbage(_))
        ));
    }
}
