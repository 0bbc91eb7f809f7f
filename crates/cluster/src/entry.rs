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

/// The format this build writes and the newest it reads.
pub const FORMAT: u32 = 1;

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
        assert_eq!(
            decode(Some("2"), &payload).unwrap_err(),
            EntryError::Newer {
                found: 2,
                supported: 1
            }
        );
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
