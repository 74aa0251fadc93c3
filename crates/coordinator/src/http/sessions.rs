//! The dashboard's login sessions, held by the coordinator: a session is a random value the
//! login sets as the cookie, naming the token it was opened with, so that logging out ends it
//! (a value derived from the token could not be withdrawn while the token stands), changing
//! or withdrawing the token ends it too, and a cookie that leaks gives away nothing of the
//! token. Sessions live in memory: a restart asks browsers to log in again. They are bounded
//! in number (the oldest go first) and in age, so logging in again and again cannot grow them.

use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};

/// How long a session lasts: the cookie's `Max-Age`.
pub(super) const SESSION_TIME: Duration = Duration::from_secs(30 * 86_400);

/// Most sessions held at once.
const MAX_SESSIONS: usize = 10_000;

/// The open sessions, by the SHA-256 of their cookie value (a lookup by a hash tells a timing
/// observer nothing about the value).
#[derive(Default)]
pub(super) struct Sessions {
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    /// Cookie hash → (the SHA-256 of the token it was opened with, when it ends).
    open: HashMap<[u8; 32], ([u8; 32], Instant)>,
    /// Cookie hashes, oldest first (some may have been closed since).
    order: VecDeque<[u8; 32]>,
}

fn digest(s: &str) -> [u8; 32] {
    Sha256::digest(s.as_bytes()).into()
}

impl Sessions {
    /// Opens a session for the holder of the token of hash `token`; returns the cookie value,
    /// or `None` without a random source.
    pub(super) fn open(&self, token: [u8; 32], now: Instant) -> Option<String> {
        let mut b = [0u8; 32];
        getrandom::getrandom(&mut b).ok()?;
        let value: String = b.iter().map(|x| format!("{x:02x}")).collect();
        let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let key = digest(&value);
        inner.open.insert(key, (token, now + SESSION_TIME));
        inner.order.push_back(key);
        while inner.open.len() > MAX_SESSIONS || inner.order.len() > 2 * MAX_SESSIONS {
            let Some(old) = inner.order.pop_front() else {
                break;
            };
            inner.open.remove(&old);
        }
        Some(value)
    }

    /// The token hash of the open session of cookie value `value`, if it is one.
    pub(super) fn token_of(&self, value: &str, now: Instant) -> Option<[u8; 32]> {
        let inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        inner
            .open
            .get(&digest(value))
            .filter(|(_, ends)| now < *ends)
            .map(|(token, _)| *token)
    }

    /// Ends the session of cookie value `value`, if there is one.
    pub(super) fn close(&self, value: &str) {
        let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        inner.open.remove(&digest(value));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_session_is_random_ends_at_logout_and_after_its_time_and_is_bounded() {
        let s = Sessions::default();
        let now = Instant::now();
        let a = s.open([1; 32], now).expect("random");
        let b = s.open([1; 32], now).expect("random");
        assert_ne!(a, b, "two logins with one token are two sessions");
        assert_eq!(s.token_of(&a, now), Some([1; 32]));
        s.close(&a);
        assert_eq!(s.token_of(&a, now), None);
        assert_eq!(s.token_of(&b, now), Some([1; 32]));
        assert_eq!(s.token_of(&b, now + SESSION_TIME), None);
        for _ in 0..MAX_SESSIONS {
            s.open([2; 32], now);
        }
        assert_eq!(s.token_of(&b, now), None, "the oldest went first");
        let inner = s.inner.lock().expect("lock");
        assert!(inner.open.len() <= MAX_SESSIONS && inner.order.len() <= 2 * MAX_SESSIONS);
    }
}
