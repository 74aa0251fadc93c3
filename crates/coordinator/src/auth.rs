//! Who may call: the farm's tokens, as the gRPC interceptor and the dashboard both check them,
//! in one place that hashes and compares, so the two ports cannot accept different things.
//!
//! A coordinator has either one token (`--token-file`, `TESSERA_TOKEN`), whose holders act as
//! one anonymous user who may do anything, or a tokens file (`--tokens-file`) that names a user
//! for each token, reread when the coordinator gets SIGHUP ([`Tokens::reload`]):
//!
//! ```text
//! # NAME   TOKEN                              [admin|worker]
//! alice    6f1d0c0e8a2b4d7f9e3c5a1b2d4f6e8a
//! bob      0b9a8c7d6e5f4a3b2c1d0e9f8a7b6c5d
//! ops      a1b2c3d4e5f6a7b8c9d0e1f2a3b4c5d6   admin
//! farm     5e4d3c2b1a0f9e8d7c6b5a4f3e2d1c0b   worker
//! ```
//!
//! Each named token has one role ([`Role`]). A user's token (no third word) and an admin's
//! serve the job API only (`tessera.v1.Jobs`, the dashboard and its HTTP API); a `worker`
//! token serves the worker API only (`tessera.v1.Workers`). So a user cannot register a
//! worker, lease another user's units and have forged results merged, or fetch the scenes and
//! files of others' jobs, which workers read; and a worker's token, which sits on every render
//! machine, cannot submit or cancel jobs. A job records the user who submitted it (fair share
//! and the per-user cap count by it), and only that user or an `admin` may cancel, pause,
//! resume, reprioritise or retry it.
//!
//! Every comparison hashes both sides first and checks every token, so neither its time nor
//! its length depends on how much of a token matched, or which one.

use std::path::Path;
use std::sync::{Arc, RwLock};

use subtle::ConstantTimeEq;
use tessera_proto::{parse_token, Secret};

/// Most users a tokens file may name.
pub const MAX_TOKENS: usize = 10_000;

/// The largest priority, either way, a user who is not an admin may give a job.
pub const MAX_USER_PRIORITY: i32 = 100;

/// Most characters of a user name.
pub const MAX_USER_CHARS: usize = 64;

/// What a token may call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// The job API: submit, follow, fetch, and change its own jobs.
    User,
    /// The job API, and may change every user's jobs and release quarantined workers.
    Admin,
    /// The worker API only: register, lease, return results, read the scenes it renders.
    Worker,
    /// Both APIs: the lone `--token-file` token, or no token at all.
    Any,
}

/// The two gRPC services a token may be allowed to call, and the HTTP port (the job API's).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Api {
    /// `tessera.v1.Jobs`, the dashboard and its HTTP API.
    Jobs,
    /// `tessera.v1.Workers`.
    Workers,
}

/// Who a call comes from, as the services see it (a request extension the token check sets).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    /// The user the token names; empty for the holder of a lone `--token-file` token.
    pub user: String,
    /// May act on every user's jobs.
    pub admin: bool,
    /// Which API the token serves.
    pub role: Role,
}

impl Caller {
    /// The caller on a farm with one token, or none: nobody in particular, who may do
    /// anything.
    pub fn anyone() -> Self {
        Self {
            user: String::new(),
            admin: true,
            role: Role::Any,
        }
    }

    /// Whether this caller may give a job priority `priority`: within ±[`MAX_USER_PRIORITY`]
    /// for a user, anything for an admin. Priority goes before fair share, so a user who could
    /// set `i32::MAX` would take the whole farm from everybody else.
    pub fn may_set_priority(&self, priority: i32) -> Result<(), String> {
        if self.admin || priority.unsigned_abs() <= MAX_USER_PRIORITY.unsigned_abs() {
            return Ok(());
        }
        Err(format!(
            "priority {priority}: a user may set -{MAX_USER_PRIORITY} to {MAX_USER_PRIORITY}; \
             only an admin may go beyond"
        ))
    }

    /// Whether this caller's token serves `api`; the refusal says which token would.
    pub fn may_call(&self, api: Api) -> Result<(), String> {
        match (self.role, api) {
            (Role::Any, _)
            | (Role::User | Role::Admin, Api::Jobs)
            | (Role::Worker, Api::Workers) => Ok(()),
            (Role::Worker, Api::Jobs) => Err(format!(
                "{}'s token is a worker token: it serves the worker API only (submit and \
                 follow jobs with a user's token)",
                self.user
            )),
            (Role::User | Role::Admin, Api::Workers) => Err(format!(
                "{}'s token is a user's token: it serves the job API only (a worker needs a \
                 token marked `worker` in the coordinator's tokens file)",
                self.user
            )),
        }
    }

    /// Whether this caller may change job `job`, submitted by `submitter`: its own, or any
    /// for an admin. The refusal names who may.
    pub fn may_change(&self, job: &str, submitter: &str, verb: &str) -> Result<(), String> {
        if self.admin || self.user == submitter {
            return Ok(());
        }
        let owner = if submitter.is_empty() {
            "an admin".to_string()
        } else {
            format!("{submitter} or an admin")
        };
        Err(format!(
            "{job} was submitted by {}; only {owner} may {verb} it",
            if submitter.is_empty() {
                "nobody named (before named tokens)"
            } else {
                submitter
            }
        ))
    }
}

/// One token and who it names.
struct Named {
    caller: Caller,
    hash: [u8; 32],
}

impl Named {
    fn new(caller: Caller, secret: &Secret) -> Self {
        Self {
            caller,
            hash: sha256(secret.expose().as_bytes()),
        }
    }
}

/// The tokens a coordinator accepts, shared by its ports; a clone sees a reload.
#[derive(Clone)]
pub struct Tokens {
    set: Arc<RwLock<Arc<Vec<Named>>>>,
}

impl std::fmt::Debug for Tokens {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tokens({} users)", self.users())
    }
}

impl Tokens {
    fn of(named: Vec<Named>) -> Self {
        Self {
            set: Arc::new(RwLock::new(Arc::new(named))),
        }
    }

    fn current(&self) -> Arc<Vec<Named>> {
        // A poisoned lock still holds a whole set: a reload swaps one Arc for another.
        self.set.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The lone token `secret`: its holders are one anonymous user who may do anything.
    pub fn one(secret: &Secret) -> Self {
        Self::of(vec![Named::new(Caller::anyone(), secret)])
    }

    /// A tokens file's text (`NAME TOKEN [admin]` a line; `#` comments, blank lines), read
    /// from `source` (for errors, which name the line and never print a token).
    pub fn parse(text: &str, source: &str) -> Result<Self, String> {
        let mut named: Vec<Named> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let at = format!("{source}:{}", i + 1);
            let line = line.split('#').next().unwrap_or_default().trim();
            if line.is_empty() {
                continue;
            }
            let words: Vec<&str> = line.split_whitespace().collect();
            let (user, token, role) = match words[..] {
                [u, t] => (u, t, Role::User),
                [u, t, "admin"] => (u, t, Role::Admin),
                [u, t, "worker"] => (u, t, Role::Worker),
                [_, _, other] => {
                    return Err(format!(
                        "{at}: the third word may only be `admin` or `worker`, not {:?}",
                        crate::error::truncate(other)
                    ))
                }
                _ => {
                    return Err(format!(
                        "{at}: expected `NAME TOKEN`, `NAME TOKEN admin` or `NAME TOKEN worker`, \
                         got {} words",
                        words.len()
                    ))
                }
            };
            check_user(user).map_err(|e| format!("{at}: {e}"))?;
            let secret = parse_token(token).map_err(|e| format!("{at}: {user}'s token: {e}"))?;
            let entry = Named::new(
                Caller {
                    user: user.to_string(),
                    admin: role == Role::Admin,
                    role,
                },
                &secret,
            );
            if let Some(other) = named.iter().find(|n| n.hash == entry.hash) {
                return Err(format!(
                    "{at}: {user}'s token is also {}'s: a token must name one user",
                    other.caller.user
                ));
            }
            if named.len() == MAX_TOKENS {
                return Err(format!("{at}: more than {MAX_TOKENS} tokens"));
            }
            named.push(entry);
        }
        if named.is_empty() {
            return Err(format!(
                "{source}: no tokens (a line is `NAME TOKEN`, `NAME TOKEN admin` or `NAME TOKEN \
                 worker`)"
            ));
        }
        Ok(Self::of(named))
    }

    /// The tokens file at `path`.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("--tokens-file {}: {e}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Reads the tokens file at `path` again and, if it is valid, accepts its tokens from now
    /// on (calls under way finish as they are); if not, keeps the tokens it had. Returns the
    /// number of tokens now accepted.
    pub fn reload(&self, path: &Path) -> Result<usize, String> {
        let fresh = Self::load(path)?.current();
        let n = fresh.len();
        *self.set.write().unwrap_or_else(|e| e.into_inner()) = fresh;
        Ok(n)
    }

    /// How many tokens are accepted.
    pub fn users(&self) -> usize {
        self.current().len()
    }

    /// What `pick` takes from the entry `is` holds for, if any: every entry is tried, each
    /// comparison in constant time, so the time taken does not tell which one matched.
    fn find<T>(&self, is: impl Fn(&Named) -> bool, pick: impl Fn(&Named) -> T) -> Option<T> {
        let set = self.current();
        let mut found = None;
        for n in set.iter() {
            if is(n) {
                found = Some(pick(n));
            }
        }
        found
    }

    /// Who presents token `presented`, if anyone.
    pub(crate) fn caller(&self, presented: &str) -> Option<Caller> {
        let hash = sha256(presented.as_bytes());
        self.find(|n| bool::from(n.hash.ct_eq(&hash)), |n| n.caller.clone())
    }

    /// Who holds the token of SHA-256 `hash` ([`token_hash`]), if it is still accepted: a
    /// dashboard session names its token so, and ends when the token is withdrawn.
    pub(crate) fn caller_of_hash(&self, hash: &[u8; 32]) -> Option<Caller> {
        self.find(|n| bool::from(n.hash.ct_eq(hash)), |n| n.caller.clone())
    }
}

/// The SHA-256 of token `presented`, as [`Tokens::caller_of_hash`] takes it.
pub(crate) fn token_hash(presented: &str) -> [u8; 32] {
    sha256(presented.as_bytes())
}

/// Checks a user name: 1 to [`MAX_USER_CHARS`] of letters, digits and `._@-`, so that it
/// prints as it is anywhere (a status line, a log, a metric label).
fn check_user(user: &str) -> Result<(), String> {
    let ok = |c: char| c.is_ascii_alphanumeric() || "._@-".contains(c);
    if user.is_empty() || user.chars().count() > MAX_USER_CHARS || !user.chars().all(ok) {
        return Err(format!(
            "user name {:?}: 1 to {MAX_USER_CHARS} letters, digits, '.', '_', '@' or '-'",
            crate::error::truncate(user)
        ));
    }
    Ok(())
}

/// The token an `Authorization` header's value carries, if it is a bearer token.
pub(crate) fn bearer(authorization: &str) -> Option<&str> {
    authorization.strip_prefix("Bearer ")
}

fn sha256(b: &[u8]) -> [u8; 32] {
    use sha2::Digest;
    sha2::Sha256::digest(b).into()
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: &str = "aaaaaaaaaaaaaaaaaaaa";
    const B: &str = "bbbbbbbbbbbbbbbbbbbb";

    #[test]
    fn only_the_token_matches_and_its_hash_names_its_holder() {
        let t = Tokens::one(&Secret::new("s3cret-s3cret-s3cret".to_string()));
        let anyone = Caller::anyone();
        assert_eq!(t.caller("s3cret-s3cret-s3cret"), Some(anyone.clone()));
        assert_eq!(t.caller("s3cret-s3cret-s3cre"), None);
        assert_eq!(t.caller(""), None);
        assert_eq!(
            t.caller_of_hash(&token_hash("s3cret-s3cret-s3cret")),
            Some(anyone)
        );
        assert_eq!(t.caller_of_hash(&token_hash("nope")), None);
        assert_eq!(bearer("Bearer abc"), Some("abc"));
        assert_eq!(bearer("Basic abc"), None);
    }

    #[test]
    fn a_tokens_file_names_each_holder_and_admins() {
        let text = format!("# who\nalice {A}\n\n  ops {B} admin # the on-call\n");
        let t = Tokens::parse(&text, "tokens").expect("parse");
        assert_eq!(t.users(), 2);
        let alice = t.caller(A).expect("alice");
        assert_eq!((alice.user.as_str(), alice.admin), ("alice", false));
        assert!(t.caller(B).expect("ops").admin);
        assert!(alice.may_change("job-000001", "alice", "cancel").is_ok());
        assert_eq!(
            alice.may_change("job-000002", "bob", "cancel"),
            Err("job-000002 was submitted by bob; only bob or an admin may cancel it".into())
        );
        assert!(t
            .caller(B)
            .expect("ops")
            .may_change("j", "bob", "cancel")
            .is_ok());
        assert!(alice.may_set_priority(100).is_ok() && alice.may_set_priority(-100).is_ok());
        assert!(alice
            .may_set_priority(i32::MAX)
            .unwrap_err()
            .contains("only an admin"));
        assert!(alice.may_set_priority(i32::MIN).is_err());
        assert!(t.caller(B).expect("ops").may_set_priority(i32::MAX).is_ok());
        // Roles: users and admins call the job API, workers the worker API, nobody both.
        assert!(alice.may_call(Api::Jobs).is_ok());
        assert!(alice
            .may_call(Api::Workers)
            .unwrap_err()
            .contains("job API only"));
        let farm = Tokens::parse(&format!("farm {A} worker\n"), "t").expect("parse");
        let farm = farm.caller(A).expect("farm");
        assert_eq!((farm.role, farm.admin), (Role::Worker, false));
        assert!(farm.may_call(Api::Workers).is_ok());
        assert!(farm
            .may_call(Api::Jobs)
            .unwrap_err()
            .contains("worker API only"));
        assert!(Caller::anyone().may_call(Api::Workers).is_ok());
        assert!(Caller::anyone().may_call(Api::Jobs).is_ok());
        assert_eq!(
            t.caller_of_hash(&token_hash(A)).map(|c| c.user),
            Some("alice".into())
        );
    }

    #[test]
    fn a_bad_tokens_file_is_refused_by_line_without_printing_a_token() {
        for (text, wanted) in [
            (
                format!("alice {A}\nbob\n"),
                "tokens:2: expected `NAME TOKEN`",
            ),
            (
                format!("alice {A} root\n"),
                "tokens:1: the third word may only be `admin` or `worker`",
            ),
            ("alice short\n".to_string(), "tokens:1: alice's token:"),
            (format!("al/ice {A}\n"), "tokens:1: user name \"al/ice\""),
            (
                format!("alice {A}\nbob {A}\n"),
                "tokens:2: bob's token is also alice's",
            ),
            ("# nothing\n".to_string(), "tokens: no tokens"),
        ] {
            let e = Tokens::parse(&text, "tokens").expect_err(&text);
            assert!(e.starts_with(wanted), "{e}");
            assert!(!e.contains(A), "{e}");
        }
    }

    #[test]
    fn a_reload_swaps_the_tokens_and_a_bad_file_keeps_the_old_ones() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("tokens");
        std::fs::write(&path, format!("alice {A}\n")).expect("write");
        let t = Tokens::load(&path).expect("load");
        let seen_by_a_port = t.clone();
        std::fs::write(&path, format!("bob {B}\n")).expect("write");
        assert_eq!(t.reload(&path), Ok(1));
        assert_eq!(
            seen_by_a_port.caller(A),
            None,
            "alice's token was withdrawn"
        );
        assert_eq!(seen_by_a_port.caller(B).map(|c| c.user), Some("bob".into()));
        std::fs::write(&path, "bob short\n").expect("write");
        assert!(t.reload(&path).is_err());
        assert!(
            seen_by_a_port.caller(B).is_some(),
            "a bad file keeps the old tokens"
        );
    }
}
