//! The farm's token, as the gRPC interceptor and the dashboard both check it: one place that
//! hashes and compares, so the two ports cannot accept different things.
//!
//! Both sides of every comparison are hashed first, so neither the comparison's time nor its
//! length depends on how much of the token matched.

use subtle::ConstantTimeEq;
use tessera_proto::Secret;

/// A configured token: its hash, and the dashboard's session value derived from it.
pub(crate) struct Token {
    hash: [u8; 32],
    session: String,
}

impl Token {
    /// The token `secret`.
    pub(crate) fn new(secret: &Secret) -> Self {
        Self {
            hash: sha256(secret.expose().as_bytes()),
            // Derived from the token, not the token itself: a cookie that leaks does not give
            // away the farm's token (which the workers and clients use too), and every session
            // ends when the token is changed.
            session: sha256(format!("tessera dashboard session\0{}", secret.expose()).as_bytes())
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect(),
        }
    }

    /// Whether `presented` is the token, compared in constant time.
    pub(crate) fn matches(&self, presented: &str) -> bool {
        bool::from(sha256(presented.as_bytes()).ct_eq(&self.hash))
    }

    /// The value of a logged-in browser's session cookie.
    pub(crate) fn session(&self) -> &str {
        &self.session
    }

    /// Whether `cookie` is the session value, compared in constant time.
    pub(crate) fn session_matches(&self, cookie: &str) -> bool {
        cookie.len() == self.session.len()
            && bool::from(cookie.as_bytes().ct_eq(self.session.as_bytes()))
    }
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

    #[test]
    fn only_the_token_matches_and_the_session_is_not_the_token() {
        let t = Token::new(&Secret::new("s3cret".to_string()));
        assert!(t.matches("s3cret"));
        assert!(!t.matches("s3cre"));
        assert!(!t.matches(""));
        assert!(t.session_matches(t.session()));
        assert!(!t.session_matches("s3cret"));
        assert_eq!(bearer("Bearer abc"), Some("abc"));
        assert_eq!(bearer("Basic abc"), None);
    }
}
