//! Bearer tokens: made, listed and revoked by `humem token`, kept hashed in
//! one JSON file that the server reads again within a second of a change.
//!
//! A token is `hm1.<id>.<secret>`: the id (8 hex digits) names it in lists
//! and revocations and may be logged; the secret is 32 random bytes. Only
//! the SHA-256 of the whole token is stored. A single fast hash is enough
//! (no key stretching) because the secret has 256 bits of entropy: nothing
//! is guessable from the hash, unlike a password.
//!
//! The file is rewritten whole through a temporary file and a rename, under
//! an exclusive lock on a `.lock` file beside it, so concurrent `humem token`
//! commands do not lose each other's changes and the server never reads a
//! half-written file.

use std::collections::HashMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Version of the token file's format.
const FILE_VERSION: u32 = 1;
/// Prefix of every token (and of its format).
const TOKEN_PREFIX: &str = "hm1";

/// What a credential may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Writes and resets its own robot's keyframes; reads its own maps and
    /// those the access rules share with it.
    Robot,
    /// Acts on every robot and reads every map.
    Admin,
}

/// One token as stored: never the token itself.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TokenRecord {
    /// Public id (8 hex digits), also inside the token.
    pub id: String,
    /// The robot the token speaks for.
    pub robot: String,
    /// What it may do.
    pub roles: Vec<Role>,
    /// SHA-256 of the token, hex.
    pub sha256: String,
    /// When it was made (seconds since the Unix epoch).
    pub created_unix: u64,
    /// Free text: who has it, what for.
    #[serde(default)]
    pub note: String,
}

/// The token file.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TokenFile {
    /// Format version ([`FILE_VERSION`]).
    pub version: u32,
    /// Every token that is valid.
    pub tokens: Vec<TokenRecord>,
}

/// Errors of reading or changing the token file.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The file is not a token file this build understands.
    #[error("{path}: not a valid token file: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// No token has that id.
    #[error("no token with id {0}")]
    UnknownId(String),
    /// A robot id that requests could never carry.
    #[error("robot id must be 1 to 128 bytes, got {0} bytes")]
    BadRobot(usize),
    /// The operating system gave no randomness.
    #[error("no randomness from the operating system: {0}")]
    Random(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TokenError + '_ {
    move |source| TokenError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of a token, hex: the form it is stored and looked up in.
pub fn token_hash(token: &str) -> String {
    hex(&Sha256::digest(token.as_bytes()))
}

/// The id inside a well-formed token (for logs: the secret never is).
pub fn token_id(token: &str) -> Option<&str> {
    let mut parts = token.split('.');
    let (prefix, id, secret) = (parts.next()?, parts.next()?, parts.next()?);
    (prefix == TOKEN_PREFIX && id.len() == 8 && secret.len() == 64 && parts.next().is_none())
        .then_some(id)
}

impl TokenFile {
    /// Reads the file; a file that does not exist holds no tokens.
    pub fn read(path: &Path) -> Result<TokenFile, TokenError> {
        let text = match std::fs::read_to_string(path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(TokenFile {
                    version: FILE_VERSION,
                    tokens: Vec::new(),
                })
            }
            Err(e) => return Err(io(path)(e)),
        };
        let file: TokenFile = serde_json::from_str(&text).map_err(|e| TokenError::Invalid {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        if file.version != FILE_VERSION {
            return Err(TokenError::Invalid {
                path: path.to_path_buf(),
                reason: format!(
                    "format version {} (this build reads {FILE_VERSION})",
                    file.version
                ),
            });
        }
        Ok(file)
    }

    /// The tokens by hash, for the server's lookups.
    pub fn by_hash(&self) -> HashMap<String, TokenRecord> {
        self.tokens
            .iter()
            .map(|t| (t.sha256.clone(), t.clone()))
            .collect()
    }
}

/// Runs `change` on the file under its lock and writes the result back
/// atomically (mode 0600).
fn update<T>(
    path: &Path,
    change: impl FnOnce(&mut TokenFile) -> Result<T, TokenError>,
) -> Result<T, TokenError> {
    let lock_path = path.with_extension("lock");
    let lock = File::create(&lock_path).map_err(io(&lock_path))?;
    lock.lock().map_err(io(&lock_path))?;
    let mut file = TokenFile::read(path)?;
    let result = change(&mut file)?;
    let text = serde_json::to_string_pretty(&file).expect("token file serialises");
    let partial = path.with_extension("partial");
    {
        let mut options = std::fs::OpenOptions::new();
        options.write(true).create(true).truncate(true);
        #[cfg(unix)]
        std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
        let mut out = options.open(&partial).map_err(io(&partial))?;
        out.write_all(text.as_bytes()).map_err(io(&partial))?;
        out.sync_all().map_err(io(&partial))?;
    }
    std::fs::rename(&partial, path).map_err(io(path))?;
    Ok(result)
}

/// Makes a token for `robot` with `roles`, stores its hash, and returns the
/// token (the only time it is ever shown) with its record.
pub fn add(
    path: &Path,
    robot: &str,
    roles: &[Role],
    note: &str,
) -> Result<(String, TokenRecord), TokenError> {
    if robot.is_empty() || robot.len() > 128 {
        return Err(TokenError::BadRobot(robot.len()));
    }
    let mut random = [0u8; 36];
    getrandom::fill(&mut random).map_err(|e| TokenError::Random(e.to_string()))?;
    let id = hex(&random[..4]);
    let token = format!("{TOKEN_PREFIX}.{id}.{}", hex(&random[4..]));
    let mut roles = roles.to_vec();
    roles.sort_by_key(|r| *r as u8);
    roles.dedup();
    let record = TokenRecord {
        id,
        robot: robot.to_string(),
        roles,
        sha256: token_hash(&token),
        created_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
        note: note.to_string(),
    };
    let stored = record.clone();
    update(path, move |file| {
        file.tokens.push(stored);
        Ok(())
    })?;
    Ok((token, record))
}

/// Removes the token with `id`; returns its record.
pub fn revoke(path: &Path, id: &str) -> Result<TokenRecord, TokenError> {
    update(path, |file| {
        let at = file
            .tokens
            .iter()
            .position(|t| t.id == id)
            .ok_or_else(|| TokenError::UnknownId(id.to_string()))?;
        Ok(file.tokens.remove(at))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_stored_hashed_and_found_by_hash() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens.json");
        let (token, record) = add(&path, "car-1", &[Role::Robot, Role::Robot], "test").unwrap();
        assert_eq!(token_id(&token), Some(record.id.as_str()));
        assert_eq!(record.roles, vec![Role::Robot]);
        let text = std::fs::read_to_string(&path).unwrap();
        let secret = token.rsplit('.').next().unwrap();
        assert!(!text.contains(secret), "the secret is never stored");
        let file = TokenFile::read(&path).unwrap();
        assert_eq!(file.by_hash()[&token_hash(&token)].robot, "car-1");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&path).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600);
        }
    }

    #[test]
    fn revoking_removes_only_that_token() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens.json");
        let (a, ra) = add(&path, "car-1", &[Role::Robot], "").unwrap();
        let (b, _) = add(&path, "ops", &[Role::Admin], "").unwrap();
        assert_ne!(a, b);
        assert_eq!(revoke(&path, &ra.id).unwrap().robot, "car-1");
        let by_hash = TokenFile::read(&path).unwrap().by_hash();
        assert!(!by_hash.contains_key(&token_hash(&a)));
        assert_eq!(by_hash[&token_hash(&b)].roles, vec![Role::Admin]);
        assert!(matches!(
            revoke(&path, &ra.id),
            Err(TokenError::UnknownId(_))
        ));
    }

    #[test]
    fn bad_files_and_robots_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens.json");
        assert!(TokenFile::read(&path).unwrap().tokens.is_empty());
        std::fs::write(&path, "{\"version\": 9, \"tokens\": []}").unwrap();
        let err = TokenFile::read(&path).unwrap_err();
        assert!(err.to_string().contains("format version 9"), "{err}");
        std::fs::write(&path, "not json").unwrap();
        assert!(matches!(
            TokenFile::read(&path),
            Err(TokenError::Invalid { .. })
        ));
        assert!(matches!(
            add(&dir.path().join("t.json"), "", &[Role::Robot], ""),
            Err(TokenError::BadRobot(0))
        ));
        assert_eq!(token_id("hm1.abcd.xyz"), None);
        assert_eq!(token_id("Bearer x"), None);
    }
}
