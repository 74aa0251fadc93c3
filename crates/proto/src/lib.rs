//! # tessera-proto
//!
//! The farm's wire protocol, `tessera.v1`, generated from `proto/tessera/v1/farm.proto` (see
//! that file for what every message and field means), and the connection plumbing every client
//! shares: the bearer token and TLS settings ([`client`]).

/// Version 1 of the protocol. Generated code; the .proto documents every item.
#[allow(missing_docs, clippy::all)]
pub mod v1 {
    tonic::include_proto!("tessera.v1");
}

pub mod client;
pub mod convert;
pub mod ids;
pub mod tags;
pub mod view;

/// The largest gRPC message the coordinator and its workers accept by default (a scene of up
/// to 32 MiB in a message, with room to spare); the coordinator raises it to fit a larger
/// `--max-scene-bytes`.
pub const MAX_MESSAGE_BYTES: usize = 48 << 20;

/// Lease and job ids are strings on the wire so that their form can change without a protocol
/// change; this is the longest kept in messages, to bound what a peer can make us store.
pub const MAX_ID_LEN: usize = 64;

/// A secret (token, private key) whose `Debug` never shows it, so that it cannot reach a log
/// through a `{:?}` of a config.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(String);

impl Secret {
    /// Wraps a secret.
    pub fn new(s: impl Into<String>) -> Self {
        Self(s.into())
    }

    /// The secret itself: only for use on the wire or in a comparison.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Secret(<redacted>)")
    }
}

/// Why a token is unusable.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// Too short to be a secret.
    #[error("the token is {0} characters long; use at least 16 (e.g. `openssl rand -hex 32`)")]
    TooShort(usize),
    /// Would not fit in an HTTP header.
    #[error("the token must be printable ASCII without spaces, at most 4096 characters")]
    BadChars,
}

/// Checks a token's form (whitespace around it, as in a file's trailing newline, is removed).
pub fn parse_token(text: &str) -> Result<Secret, TokenError> {
    let t = text.trim();
    if t.len() > 4096 || !t.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(TokenError::BadChars);
    }
    if t.len() < 16 {
        return Err(TokenError::TooShort(t.len()));
    }
    Ok(Secret(t.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_do_not_print_and_tokens_are_checked() {
        let s = parse_token("  0123456789abcdef0123\n").expect("token");
        assert_eq!(s.expose(), "0123456789abcdef0123");
        assert!(!format!("{s:?}").contains("0123"));
        assert!(matches!(parse_token("short"), Err(TokenError::TooShort(5))));
        assert!(matches!(
            parse_token("0123456789 abcdef0123"),
            Err(TokenError::BadChars)
        ));
    }
}

/// Typed reasons a coordinator attaches to a refusal, where a peer acts on the reason rather
/// than the code alone: `NOT_FOUND` is also the answer for an unknown job, and a message's
/// words are for people and may change.
pub mod reason {
    use tonic::Status;

    /// The metadata key that carries the reason.
    pub const KEY: &str = "tessera-reason";

    /// The worker credential a call quoted is not one this coordinator boot issued (it
    /// restarted, or the credential was never valid): the worker registers again.
    pub const UNKNOWN_WORKER: &str = "unknown-worker";

    /// A `NOT_FOUND` refusal that says the caller's worker credential is unknown.
    pub fn unknown_worker(message: impl Into<String>) -> Status {
        let mut s = Status::not_found(message);
        s.metadata_mut().insert(
            KEY,
            tonic::metadata::MetadataValue::from_static(UNKNOWN_WORKER),
        );
        s
    }

    /// Whether `s` says the caller's worker credential is unknown.
    pub fn is_unknown_worker(s: &Status) -> bool {
        s.code() == tonic::Code::NotFound
            && s.metadata().get(KEY).and_then(|v| v.to_str().ok()) == Some(UNKNOWN_WORKER)
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        /// The reason is in the metadata, not the words: an unknown job is `NOT_FOUND` too,
        /// and says "unknown worker" nowhere that matters.
        #[test]
        fn only_the_typed_reason_says_the_worker_is_unknown() {
            assert!(is_unknown_worker(&unknown_worker("anything at all")));
            assert!(!is_unknown_worker(&Status::not_found(
                "unknown worker w1-2"
            )));
            let mut other = Status::internal("x");
            other.metadata_mut().insert(
                KEY,
                tonic::metadata::MetadataValue::from_static(UNKNOWN_WORKER),
            );
            assert!(!is_unknown_worker(&other));
        }
    }
}
