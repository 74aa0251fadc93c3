//! The farm's ids, typed. On the wire they are strings, so that their form can change without a
//! protocol change; everything past the conversion layer holds these types, and only the
//! coordinator's handlers parse them. Each parse accepts exactly the form [`Display`] writes
//! (no sign, no leading zeros, nothing trailing), so an id read back prints as the same string
//! a peer sent, and two spellings of one id cannot exist.
//!
//! [`Display`]: std::fmt::Display

use std::fmt;
use std::str::FromStr;

use crate::MAX_ID_LEN;

/// A string that is not an id of the kind expected. Its message quotes at most
/// [`MAX_ID_LEN`] characters of what was sent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("malformed {kind} id {text:?} (expected {form})")]
pub struct BadId {
    /// Which kind of id was expected.
    pub kind: &'static str,
    /// What the peer sent, cut to [`MAX_ID_LEN`] characters.
    pub text: String,
    /// The expected form, for the message.
    pub form: &'static str,
}

impl BadId {
    fn new(kind: &'static str, form: &'static str, text: &str) -> Self {
        Self {
            kind,
            text: text.chars().take(MAX_ID_LEN).collect(),
            form,
        }
    }
}

/// A decimal number as [`u64`]'s `Display` writes it: digits only, no leading zero.
fn canonical_u64(s: &str) -> Option<u64> {
    let canonical = !s.is_empty()
        && s.len() <= 20
        && s.bytes().all(|b| b.is_ascii_digit())
        && (s == "0" || !s.starts_with('0'));
    canonical.then(|| s.parse().ok()).flatten()
}

/// A job: `job-NNNNNN`, written with at least six digits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct JobId(pub u64);

impl fmt::Display for JobId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "job-{:06}", self.0)
    }
}

impl serde::Serialize for JobId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl FromStr for JobId {
    type Err = BadId;

    fn from_str(s: &str) -> Result<Self, BadId> {
        let bad = || BadId::new("job", "job-NNNNNN", s);
        let digits = s.strip_prefix("job-").ok_or_else(bad)?;
        // Any number of digits: a person may type `job-4` for `job-000004`. Job ids are never
        // echoed back for a peer to match, so a second spelling is harmless here.
        if digits.is_empty() || digits.len() > 20 || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        digits.parse().map(JobId).map_err(|_| bad())
    }
}

impl JobId {
    /// The default output file name of the job: `job-NNNNNN.exr`.
    pub fn default_output_name(self) -> String {
        format!("{self}.exr")
    }

    /// Whether `name` is the default output name of some job, or of a frame of some
    /// frame-range job (`job-NNNNNN.####.exr`). Such names are kept for the jobs they name, so
    /// that nobody can take a later job's name in advance.
    pub fn is_default_output_name(name: &str) -> bool {
        let Some(stem) = name.strip_suffix(".exr") else {
            return false;
        };
        let stem = match stem.rsplit_once('.') {
            Some((id, frame)) if !frame.is_empty() && frame.bytes().all(|b| b.is_ascii_digit()) => {
                id
            }
            _ => stem,
        };
        stem.parse::<JobId>().is_ok()
    }
}

/// Parses `{prefix}{epoch}-{n}`, the form of lease and worker ids.
fn epoch_and_number(s: &str, prefix: char) -> Option<(u64, u64)> {
    let (e, n) = s.strip_prefix(prefix)?.split_once('-')?;
    Some((canonical_u64(e)?, canonical_u64(n)?))
}

/// An id of one coordinator boot (`epoch`) and a number within it, written
/// `{prefix}{epoch}-{n}`: two types of one form, so that a lease id can never be passed where a
/// worker id is meant.
macro_rules! epoch_id {
    ($(#[$doc:meta])* $name:ident, $prefix:literal, $kind:literal, $form:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub struct $name {
            /// The coordinator boot that issued it.
            pub epoch: u64,
            /// Its number within that boot.
            pub n: u64,
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!($prefix, "{}-{}"), self.epoch, self.n)
            }
        }

        impl serde::Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }

        impl FromStr for $name {
            type Err = BadId;

            fn from_str(s: &str) -> Result<Self, BadId> {
                epoch_and_number(s, $prefix)
                    .map(|(epoch, n)| $name { epoch, n })
                    .ok_or_else(|| BadId::new($kind, $form, s))
            }
        }
    };
}

epoch_id!(
    /// A lease: `L{epoch}-{n}`. The epoch lets the coordinator tell a lease from before a
    /// restart from a new one with the same number.
    LeaseId,
    'L',
    "lease",
    "L<boot>-<number>"
);

epoch_id!(
    /// A worker's public id, as `tessera workers` lists it: `w{epoch}-{n}`.
    WorkerId,
    'w',
    "worker",
    "w<boot>-<number>"
);

/// What a worker quotes in its calls: its public id and the secret only `Register`'s reply
/// carries, `{id}.{secret}`. Anyone can read the public id from `tessera workers`; only the
/// worker that registered knows the secret, so only it can act as that worker.
#[derive(Clone, PartialEq, Eq)]
pub struct WorkerCredential {
    /// The public id.
    pub id: WorkerId,
    /// The secret half.
    pub secret: String,
}

impl fmt::Debug for WorkerCredential {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.<redacted>", self.id)
    }
}

impl fmt::Display for WorkerCredential {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.id, self.secret)
    }
}

impl FromStr for WorkerCredential {
    type Err = BadId;

    fn from_str(s: &str) -> Result<Self, BadId> {
        let bad = || {
            // Never echo the secret half back.
            BadId::new(
                "worker",
                "w<boot>-<number>.<secret>",
                s.split('.').next().unwrap_or_default(),
            )
        };
        let (id, secret) = s.split_once('.').ok_or_else(bad)?;
        let id = id.parse().map_err(|_| bad())?;
        if secret.is_empty() || secret.len() > MAX_ID_LEN {
            return Err(bad());
        }
        Ok(Self {
            id,
            secret: secret.to_string(),
        })
    }
}

/// Whether `s` is a SHA-256 as the protocol writes one, 64 lower-case hex digits: the
/// address of a scene's file (`AssetRef`, `AssetChunk`). Checked wherever one arrives, since
/// it becomes a file name on both the coordinator and the worker.
pub fn is_sha256(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_round_trip_through_their_one_written_form() {
        for id in [0, 1, 42, 999_999, 1_000_000, u64::MAX] {
            let j = JobId(id);
            assert_eq!(j.to_string().parse::<JobId>(), Ok(j));
            let l = LeaseId { epoch: id, n: 7 };
            assert_eq!(l.to_string().parse::<LeaseId>(), Ok(l));
            let w = WorkerId { epoch: 3, n: id };
            assert_eq!(w.to_string().parse::<WorkerId>(), Ok(w));
        }
        let c: WorkerCredential = "w3-9.abc123".parse().expect("credential");
        assert_eq!(c.id, WorkerId { epoch: 3, n: 9 });
        assert_eq!(c.to_string(), "w3-9.abc123");
        assert_eq!(format!("{c:?}"), "w3-9.<redacted>");
        assert!(JobId::is_default_output_name("job-000004.exr"));
        assert_eq!("job-4".parse::<JobId>(), Ok(JobId(4)));
        assert!(!JobId::is_default_output_name("job.exr"));
        // A frame of a frame-range job's default names, too.
        assert!(JobId::is_default_output_name("job-000004.0012.exr"));
        assert!(!JobId::is_default_output_name("job-000004.x.exr"));
        assert!(!JobId::is_default_output_name("shot.0012.exr"));
        assert_eq!(JobId(4).default_output_name(), "job-000004.exr");
    }

    #[test]
    fn other_spellings_and_junk_are_refused_by_name() {
        for s in [
            "",
            "job-",
            "job-+00001",
            "job-00000a",
            "JOB-000001",
            "job-000001 ",
            "job-99999999999999999999999",
        ] {
            assert!(s.parse::<JobId>().is_err(), "{s:?}");
        }
        for s in [
            "", "L", "L1", "L1-", "L-1", "L01-2", "L1-02", "L+1-2", "L1-2-3", "l1-2",
        ] {
            assert!(s.parse::<LeaseId>().is_err(), "{s:?}");
        }
        for s in ["w1-2", "w1-2.", ".x", "w1.x", "wx-2.s"] {
            assert!(s.parse::<WorkerCredential>().is_err(), "{s:?}");
        }
        let e = "x".repeat(500).parse::<LeaseId>().expect_err("junk");
        assert_eq!(e.text.len(), MAX_ID_LEN);
        assert!(e.to_string().starts_with("malformed lease id"), "{e}");
        let e = "w1-x.topsecret"
            .parse::<WorkerCredential>()
            .expect_err("bad");
        assert!(!e.to_string().contains("topsecret"), "{e}");
    }
}
