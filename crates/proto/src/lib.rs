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
