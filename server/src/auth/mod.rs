//! Who is calling, and what they may do: credentials (a bearer token from
//! the token file, or a verified client certificate) mapped to a robot id
//! and roles, and the rules for writing and reading.
//!
//! The handlers ask two questions, in this order: [`Authenticator::caller`]
//! (UNAUTHENTICATED without a valid credential, before the request is even
//! validated) and, once the request names its robot, [`Caller::acts_for`]
//! (PERMISSION_DENIED for another robot's id, unless the caller is an
//! admin). Reads are not refused but narrowed: [`Caller::readable_robots`]
//! goes into the query's eligibility, so any scope returns only keyframes
//! the caller may read. Every refusal is logged as a structured event
//! (target `humem::audit`: caller, RPC, reason) and counted.
//!
//! With authentication off (no token file, no required client
//! certificates), every caller is [`Caller::Anyone`] and may do everything:
//! the zero-configuration loopback sidecar.

pub mod tokens;

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::{Arc, RwLock};

use tonic::{Request, Status};

use crate::config::{AuthConfig, ClientAuth, TlsSettings};
use crate::metrics;
use tokens::{Role, TokenFile, TokenRecord};

/// A caller, once authenticated.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Caller {
    /// Authentication is off: anyone may do anything.
    Anyone,
    /// A credential that speaks for one robot.
    Robot {
        /// The robot id requests must carry.
        robot: String,
        /// Acts on every robot and reads everything.
        admin: bool,
        /// Which credential, for the audit log: `token <id>` or
        /// `certificate <common name>` (never a secret).
        credential: String,
    },
}

impl Caller {
    /// Whether the caller may write, reset or query as `robot_id`.
    pub fn may_act_for(&self, robot_id: &str) -> bool {
        match self {
            Caller::Anyone => true,
            Caller::Robot { robot, admin, .. } => *admin || robot == robot_id,
        }
    }

    /// The robots whose keyframes the caller may read; `None`: all.
    pub fn readable_robots(&self, groups: &BTreeMap<String, Vec<String>>) -> Option<Vec<String>> {
        match self {
            Caller::Anyone | Caller::Robot { admin: true, .. } => None,
            Caller::Robot { robot, .. } => {
                let mut readable = BTreeSet::from([robot.clone()]);
                for members in groups.values().filter(|m| m.contains(robot)) {
                    readable.extend(members.iter().cloned());
                }
                Some(readable.into_iter().collect())
            }
        }
    }

    /// How the caller is named in the audit log.
    pub fn describe(&self) -> String {
        match self {
            Caller::Anyone => "anyone".into(),
            Caller::Robot {
                robot, credential, ..
            } => format!("{robot} ({credential})"),
        }
    }
}

/// Why a request was refused, as counted in
/// `humem_auth_denied_total{reason}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Denial {
    /// No credential, or one that is not valid.
    Unauthenticated,
    /// A valid credential acting beyond its rights.
    PermissionDenied,
}

/// Logs and counts a refusal and makes its status.
pub fn deny(rpc: &'static str, caller: &str, denial: Denial, reason: String) -> Status {
    let (label, status) = match denial {
        Denial::Unauthenticated => ("unauthenticated", Status::unauthenticated(reason.clone())),
        Denial::PermissionDenied => (
            "permission_denied",
            Status::permission_denied(reason.clone()),
        ),
    };
    metrics::AUTH_DENIED.with_label_values(&[rpc, label]).inc();
    tracing::warn!(target: "humem::audit", caller, rpc, denial = label, reason, "request denied");
    status
}

/// The access rules that can change while the server runs: which robots
/// share their maps, and which certificate names act as admins. Swapped
/// whole, so a request sees the old rules or the new, never half of each.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AccessRules {
    /// `auth.groups`: every robot of a group reads every other's maps.
    pub groups: BTreeMap<String, Vec<String>>,
    /// `auth.certificate_admins`: certificate names with the admin role.
    pub certificate_admins: Vec<String>,
}

impl AccessRules {
    /// The rules of an `[auth]` section.
    pub fn of(auth: &AuthConfig) -> AccessRules {
        AccessRules {
            groups: auth.groups.clone(),
            certificate_admins: auth.certificate_admins.clone(),
        }
    }
}

/// Reads the access rules again (the configuration file, as at start), or
/// says why it cannot.
pub type RulesSource = Box<dyn Fn() -> Result<AccessRules, String> + Send + 'static>;

/// Authenticates requests against the token file and client certificates.
#[derive(Clone)]
pub struct Authenticator {
    enabled: bool,
    tokens: Arc<RwLock<HashMap<String, TokenRecord>>>,
    rules: Arc<RwLock<Arc<AccessRules>>>,
}

/// Whether these settings make every caller show credentials: a token
/// file, or client certificates required on the gRPC port.
pub fn requires_credentials(auth: &AuthConfig, tls: &TlsSettings) -> bool {
    auth.tokens_file.is_some()
        || (tls.client_ca.is_some() && tls.client_auth == ClientAuth::Required)
}

impl Authenticator {
    /// Authentication off: every caller is [`Caller::Anyone`].
    pub fn disabled() -> Authenticator {
        Authenticator {
            enabled: false,
            tokens: Arc::default(),
            rules: Arc::default(),
        }
    }

    /// Reads the token file (an unreadable one stops the start) and, on a
    /// Tokio runtime, starts watching it: a token added or revoked takes
    /// effect within a second. With `rules_file`, the file the access rules
    /// come from (the configuration file) is watched too: a change to
    /// `auth.groups` or `auth.certificate_admins` takes effect within a
    /// second, read through `reread`; a file that cannot be read or is
    /// invalid keeps the rules in force, with a warning, as a broken token
    /// file does.
    pub fn start(
        auth: &AuthConfig,
        tls: &TlsSettings,
        rules_file: Option<(std::path::PathBuf, RulesSource)>,
    ) -> Result<Authenticator, tokens::TokenError> {
        let enabled = requires_credentials(auth, tls);
        let files: Vec<_> = auth.tokens_file.iter().cloned().collect();
        let seen = crate::watch::Snapshot::of(&files);
        let table = match &auth.tokens_file {
            Some(path) => TokenFile::read(path)?.by_hash(),
            None => HashMap::new(),
        };
        let authenticator = Authenticator {
            enabled,
            tokens: Arc::new(RwLock::new(table)),
            rules: Arc::new(RwLock::new(Arc::new(AccessRules::of(auth)))),
        };
        if let Some((path, reread)) = rules_file {
            let files = vec![path];
            let seen = crate::watch::Snapshot::of(&files);
            let rules = Arc::downgrade(&authenticator.rules);
            crate::watch::on_change(files, seen, move || {
                let Some(rules) = rules.upgrade() else {
                    return false;
                };
                match reread() {
                    Ok(new) => {
                        let mut current = rules.write().unwrap_or_else(|p| p.into_inner());
                        if **current != new {
                            tracing::info!(
                                groups = new.groups.len(),
                                certificate_admins = new.certificate_admins.len(),
                                "access rules changed: reloaded (auth.groups, auth.certificate_admins)"
                            );
                            *current = Arc::new(new);
                        }
                    }
                    Err(e) => {
                        tracing::warn!(error = %e, "configuration file changed but cannot be read; keeping the access rules in force");
                    }
                }
                true
            });
        }
        if let Some(path) = auth.tokens_file.clone() {
            let tokens = Arc::downgrade(&authenticator.tokens);
            crate::watch::on_change(files, seen, move || {
                let Some(tokens) = tokens.upgrade() else {
                    return false;
                };
                match TokenFile::read(&path) {
                    Ok(file) => {
                        let table = file.by_hash();
                        tracing::info!(tokens = table.len(), "token file changed: reloaded");
                        *tokens.write().unwrap_or_else(|p| p.into_inner()) = table;
                    }
                    Err(e) => {
                        tracing::warn!(error = %e, "token file changed but cannot be read; keeping the previous tokens");
                    }
                }
                true
            });
        }
        Ok(authenticator)
    }

    /// Whether credentials are required.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// The access rules in force now (one snapshot: use it for a whole
    /// request).
    pub fn rules(&self) -> Arc<AccessRules> {
        self.rules.read().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// The caller of `request`: from its bearer token if it sends one, else
    /// from its verified client certificate; UNAUTHENTICATED (logged and
    /// counted) if neither is valid.
    pub fn caller<T>(&self, rpc: &'static str, request: &Request<T>) -> Result<Caller, Status> {
        if !self.enabled {
            return Ok(Caller::Anyone);
        }
        let unauthenticated =
            |caller: &str, reason: String| deny(rpc, caller, Denial::Unauthenticated, reason);
        if let Some(value) = request.metadata().get("authorization") {
            let token = value
                .to_str()
                .ok()
                .and_then(|v| v.strip_prefix("Bearer "))
                .map(str::trim)
                .ok_or_else(|| {
                    unauthenticated(
                        "unknown",
                        "authorization: expected \"Bearer <token>\"".into(),
                    )
                })?;
            let id = tokens::token_id(token);
            let record = self
                .tokens
                .read()
                .unwrap_or_else(|p| p.into_inner())
                .get(&tokens::token_hash(token))
                .cloned();
            return match record {
                Some(record) => Ok(Caller::Robot {
                    admin: record.roles.contains(&Role::Admin),
                    credential: format!("token {}", record.id),
                    robot: record.robot,
                }),
                None => Err(unauthenticated(
                    &match id {
                        Some(id) => format!("token {id}"),
                        None => "malformed token".into(),
                    },
                    "unknown or revoked token".into(),
                )),
            };
        }
        if let Some(name) = certificate_name(request) {
            return Ok(Caller::Robot {
                admin: self.rules().certificate_admins.contains(&name),
                credential: format!("certificate {name}"),
                robot: name,
            });
        }
        Err(unauthenticated(
            "anonymous",
            "no credential: send \"authorization: Bearer <token>\" or a client certificate".into(),
        ))
    }

    /// PERMISSION_DENIED (logged and counted) unless `caller` may act for
    /// `robot_id`; `field` names where the id came from.
    pub fn check_acts_for(
        &self,
        rpc: &'static str,
        caller: &Caller,
        field: &str,
        robot_id: &str,
    ) -> Result<(), Status> {
        if caller.may_act_for(robot_id) {
            return Ok(());
        }
        Err(deny(
            rpc,
            &caller.describe(),
            Denial::PermissionDenied,
            format!("{field}: this credential may not act for robot {robot_id:?}"),
        ))
    }
}

/// The common name of the verified client certificate, if the connection
/// has one (mutual TLS: rustls verified the chain in the handshake).
fn certificate_name<T>(request: &Request<T>) -> Option<String> {
    use x509_parser::prelude::{FromDer, X509Certificate};
    let certificates = request.peer_certs()?;
    let leaf = certificates.first()?;
    let (_, parsed) = X509Certificate::from_der(leaf.as_ref()).ok()?;
    let name = parsed
        .subject()
        .iter_common_name()
        .next()?
        .as_str()
        .ok()?
        .to_string();
    (!name.is_empty()).then_some(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robot(name: &str, admin: bool) -> Caller {
        Caller::Robot {
            robot: name.into(),
            admin,
            credential: "token 00000000".into(),
        }
    }

    #[test]
    fn robots_act_for_themselves_and_admins_for_all() {
        assert!(robot("car-1", false).may_act_for("car-1"));
        assert!(!robot("car-1", false).may_act_for("car-2"));
        assert!(robot("ops", true).may_act_for("car-2"));
        assert!(Caller::Anyone.may_act_for("car-2"));
    }

    #[test]
    fn groups_share_maps_among_their_members_only() {
        let groups = BTreeMap::from([
            (
                "north".to_string(),
                vec!["car-1".to_string(), "car-2".to_string()],
            ),
            (
                "depot".to_string(),
                vec!["car-2".to_string(), "van-9".to_string()],
            ),
        ]);
        assert_eq!(
            robot("car-1", false).readable_robots(&groups),
            Some(vec!["car-1".to_string(), "car-2".to_string()])
        );
        assert_eq!(
            robot("car-2", false).readable_robots(&groups),
            Some(vec!["car-1".into(), "car-2".into(), "van-9".into()])
        );
        assert_eq!(
            robot("car-7", false).readable_robots(&groups),
            Some(vec!["car-7".to_string()])
        );
        assert_eq!(robot("ops", true).readable_robots(&groups), None);
        assert_eq!(Caller::Anyone.readable_robots(&groups), None);
    }

    #[tokio::test]
    async fn tokens_authenticate_and_revocations_take_effect() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens.json");
        let (token, record) = tokens::add(&path, "car-1", &[Role::Robot], "").unwrap();
        let auth = Authenticator::start(
            &AuthConfig {
                tokens_file: Some(path.clone()),
                ..AuthConfig::default()
            },
            &TlsSettings::default(),
            None,
        )
        .unwrap();
        let with = |value: &str| {
            let mut request = Request::new(());
            request
                .metadata_mut()
                .insert("authorization", value.parse().unwrap());
            request
        };
        let caller = auth
            .caller("Stats", &with(&format!("Bearer {token}")))
            .unwrap();
        assert_eq!(caller, robot("car-1", false).with_credential(&record.id));
        for value in ["Bearer hm1.00000000.x", "Basic abc", "Bearer "] {
            let status = auth.caller("Stats", &with(value)).unwrap_err();
            assert_eq!(status.code(), tonic::Code::Unauthenticated, "{value}");
        }
        let status = auth.caller("Stats", &Request::new(())).unwrap_err();
        assert_eq!(status.code(), tonic::Code::Unauthenticated);
        assert!(status.message().contains("no credential"));

        tokens::revoke(&path, &record.id).unwrap();
        let started = std::time::Instant::now();
        while auth
            .caller("Stats", &with(&format!("Bearer {token}")))
            .is_ok()
        {
            assert!(started.elapsed() < std::time::Duration::from_secs(3));
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        assert!(
            Authenticator::disabled()
                .caller("Stats", &Request::new(()))
                .unwrap()
                == Caller::Anyone
        );
    }

    impl Caller {
        fn with_credential(self, id: &str) -> Caller {
            match self {
                Caller::Robot { robot, admin, .. } => Caller::Robot {
                    robot,
                    admin,
                    credential: format!("token {id}"),
                },
                other => other,
            }
        }
    }
}
