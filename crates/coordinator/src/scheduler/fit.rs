//! Which workers may take which jobs, and draining.
//!
//! A worker reports its memory and CPU features and carries its operator's tags; a job may
//! require tags and a least memory ([`crate::store::JobRecord::require`]). The lease loop skips
//! the jobs a worker does not fit, and a job that no connected worker fits says so in its
//! status ("waiting: no worker has tag big-mem") rather than waiting in silence.
//!
//! A drained worker (`tessera workers --drain`, or a worker's own SIGTERM) gets nothing new;
//! the worker learns it from its next heartbeat or lease call, hands back what it has not
//! started, finishes the rest and leaves. Once told, the worker keeps the drain itself (and
//! says so when it registers again after a coordinator restart), so a restart does not undo it.

use std::time::Instant;

use tessera_proto::ids::WorkerId;
use tessera_proto::tags::{meets, memory_words, CPU_PREFIX};

use super::Scheduler;
use crate::error::Refusal;
use crate::store::JobRecord;

/// What a worker says it has, for matching against jobs' requirements.
#[derive(Clone, Debug, Default)]
pub struct Capabilities {
    /// Memory it may use, in bytes (0: unknown, which meets no minimum).
    pub memory_bytes: u64,
    /// Its CPU features (`avx2`, …), which `cpu:FEATURE` requirements match.
    pub cpu_features: Vec<String>,
    /// Its operator tags.
    pub tags: Vec<String>,
    /// The Open Image Denoise version it loaded (0: it does not denoise), for frames that
    /// wait to be denoised ([`super::denoise`]).
    pub denoise_version: i32,
}

impl Capabilities {
    /// Whether a worker with these capabilities may take units of a job with `rec`'s
    /// requirements.
    pub fn fits(&self, rec: &JobRecord) -> bool {
        self.memory_bytes >= rec.min_memory
            && rec
                .require
                .iter()
                .all(|r| meets(r, &self.tags, &self.cpu_features))
    }
}

impl Scheduler {
    /// Records what worker `w` reported having.
    pub fn set_capabilities(&mut self, w: u64, caps: Capabilities) {
        if let Some(x) = self.workers.get_mut(&w) {
            x.caps = caps;
        }
    }

    /// Whether worker `w` is draining.
    pub fn draining(&self, w: u64) -> bool {
        self.workers.get(&w).is_some_and(|x| x.draining)
    }

    /// Marks worker `w` draining: it is leased nothing more.
    pub fn set_draining(&mut self, w: u64) {
        if let Some(x) = self.workers.get_mut(&w) {
            x.draining = true;
        }
    }

    /// Drains the live workers named `who`, or the one whose public id it is; returns their
    /// ids.
    pub fn drain(&mut self, who: &str, now: Instant) -> Result<Vec<WorkerId>, Refusal> {
        let by_id: Option<WorkerId> = who.parse().ok();
        let lease_time = self.policy.lease_time;
        let mut drained = Vec::new();
        for (&n, w) in self.workers.iter_mut() {
            let id = WorkerId {
                epoch: self.epoch,
                n,
            };
            if (by_id == Some(id) || w.name == who) && w.alive(now, lease_time) {
                w.draining = true;
                drained.push(id);
            }
        }
        if drained.is_empty() {
            return Err(Refusal::NotFound(format!(
                "no live worker is named {:?} or has that id (tessera workers lists them)",
                who.escape_debug().to_string()
            )));
        }
        Ok(drained)
    }

    /// Lifts the quarantine of the workers named `who` (every quarantined worker of that
    /// name), or of the one whose public id it is; returns their ids. Their invalid results
    /// and any conviction are forgotten: an admin who released one has judged it (a bad build
    /// replaced, a check since fixed), and its next invalid results count from zero.
    pub fn release_quarantine(&mut self, who: &str) -> Result<Vec<WorkerId>, Refusal> {
        let by_id: Option<WorkerId> = who.parse().ok();
        let mut released = Vec::new();
        for (&n, w) in self.workers.iter_mut() {
            let id = WorkerId {
                epoch: self.epoch,
                n,
            };
            if (by_id == Some(id) || w.name == who) && w.quarantined {
                w.quarantined = false;
                w.convicted = None;
                w.bad_results = 0;
                released.push(id);
            }
        }
        if released.is_empty() {
            return Err(Refusal::NotFound(format!(
                "no quarantined worker is named {:?} or has that id (tessera workers lists \
                 them)",
                who.escape_debug().to_string()
            )));
        }
        Ok(released)
    }

    /// Why no connected worker may work, when none may: which are quarantined (the first few,
    /// with why) and how many are draining, or that none is connected.
    fn nobody_may_work(&self, now: Instant) -> String {
        let lease_time = self.policy.lease_time;
        let alive = || self.workers.values().filter(|w| w.alive(now, lease_time));
        let quarantined: Vec<String> = alive()
            .filter(|w| w.quarantined)
            .map(|w| match &w.convicted {
                Some(why) => format!("{} ({why})", w.name),
                None => format!("{} (after {} invalid results)", w.name, w.bad_results),
            })
            .collect();
        let draining = alive().filter(|w| w.draining && !w.quarantined).count();
        if quarantined.is_empty() && draining == 0 {
            return "no worker is connected".into();
        }
        let mut why = Vec::new();
        if !quarantined.is_empty() {
            let shown = quarantined.len().min(3);
            why.push(format!(
                "{} quarantined: {}{} (an admin may release one: tessera workers --release NAME)",
                quarantined.len(),
                quarantined[..shown].join(", "),
                if quarantined.len() > shown {
                    ", …"
                } else {
                    ""
                }
            ));
        }
        if draining > 0 {
            why.push(format!("{draining} draining"));
        }
        format!("no connected worker may work: {}", why.join("; "))
    }

    /// Why job `rec`, which has units to hand out, gets none: no connected worker that may
    /// work fits its requirements. `None` when one does.
    pub(super) fn waiting(&self, rec: &JobRecord, now: Instant) -> Option<String> {
        let lease_time = self.policy.lease_time;
        let able: Vec<&super::Worker> = self
            .workers
            .values()
            .filter(|w| {
                w.alive(now, lease_time) && !w.draining && !w.quarantined && w.convicted.is_none()
            })
            .collect();
        if able.is_empty() {
            return Some(self.nobody_may_work(now));
        }
        let able: Vec<&super::Worker> = able
            .into_iter()
            .filter(|w| !super::failures::on_blocklist(&rec.blocklist, w))
            .collect();
        if able.is_empty() {
            return Some(format!(
                "every connected worker is blocklisted for it after failing its units ({})",
                rec.blocklist.join(", ")
            ));
        }
        if able.iter().any(|w| w.caps.fits(rec)) {
            return None;
        }
        for r in &rec.require {
            if !able
                .iter()
                .any(|w| meets(r, &w.caps.tags, &w.caps.cpu_features))
            {
                return Some(match r.strip_prefix(CPU_PREFIX) {
                    Some(f) => format!("no worker has CPU feature {f}"),
                    None => format!("no worker has tag {r}"),
                });
            }
        }
        // Each tag is met by some worker: memory, or no one worker with them all.
        let tagged: Vec<&&super::Worker> = able
            .iter()
            .filter(|w| {
                rec.require
                    .iter()
                    .all(|r| meets(r, &w.caps.tags, &w.caps.cpu_features))
            })
            .collect();
        if tagged.is_empty() {
            return Some(format!(
                "no one worker has all of: {}",
                rec.require.join(", ")
            ));
        }
        let most = tagged
            .iter()
            .map(|w| w.caps.memory_bytes)
            .max()
            .unwrap_or(0);
        let with = if rec.require.is_empty() {
            String::new()
        } else {
            format!(" with {}", rec.require.join(", "))
        };
        Some(format!(
            "no worker{with} has {} of memory (the most any has is {})",
            memory_words(rec.min_memory),
            memory_words(most)
        ))
    }
}
