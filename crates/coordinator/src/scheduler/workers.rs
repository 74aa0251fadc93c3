//! Workers: registration, the secret each quotes, the hosts they come from, and quarantine
//! after invalid results. A worker's public id is listed (`tessera workers`); only its secret,
//! returned once by `Register`, lets a caller act as it.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use tessera_proto::ids::{JobId, WorkerCredential, WorkerId};

use super::fit::Capabilities;
use super::leases::requeue;
use super::Scheduler;
use crate::error::Refusal;
use crate::job::{Rate, Unit};

/// A worker as seen by the coordinator.
#[derive(Debug)]
pub struct Worker {
    /// The secret half of its id, issued at registration: every later call must quote it, so
    /// nobody who only saw the public id (`tessera workers` lists it) can act as this worker.
    pub secret: String,
    /// Name it gave.
    pub name: String,
    /// Cores it reported.
    pub cores: u32,
    /// Its version.
    pub version: String,
    /// Last call.
    pub last_seen: Instant,
    /// Units merged from it.
    pub units_done: u64,
    /// Samples merged from it.
    pub samples_done: u64,
    /// Results refused as invalid.
    pub bad_results: u64,
    /// Said goodbye.
    pub gone: bool,
    /// Sent too many invalid results, or convicted by an audit: gets no more work.
    pub quarantined: bool,
    /// Why an audit convicted it, if one did.
    pub convicted: Option<String>,
    /// Audited units whose copies disagree and that it rendered, until the coordinator's own
    /// render of each decides (shown as "suspect"; it keeps working meanwhile).
    pub disputes: BTreeSet<(JobId, Unit)>,
    /// Its results that another worker's copy matched bit for bit.
    pub audits_passed: u64,
    /// Audited jobs it gave results to: those already ended when it is convicted are named
    /// in the conviction's record.
    pub jobs: BTreeSet<JobId>,
    /// The address it registered from (empty when unknown).
    pub host: String,
    /// Its merged samples over the last seconds.
    pub rate: Rate,
    /// What it reported having, for jobs' requirements.
    pub caps: Capabilities,
    /// Drained: it is leased nothing more, and leaves once its units are in.
    pub draining: bool,
    /// Its allowance of log lines.
    pub log_bucket: super::logs::LogBucket,
}

impl Worker {
    /// The machine it runs on, as failure and lapse limits count machines: the address it
    /// registered from, or its name where that is unknown.
    pub fn machine(&self) -> &str {
        if self.host.is_empty() {
            &self.name
        } else {
            &self.host
        }
    }

    /// Whether it counts as alive at `now`: it called within `lease_time` and has not said
    /// goodbye.
    pub fn alive(&self, now: Instant, lease_time: Duration) -> bool {
        !self.gone && now.duration_since(self.last_seen) <= lease_time
    }

    /// Why this worker, whose public id is `id`, gets nothing: quarantined after invalid
    /// results, or convicted by an audit; `None` if it may work.
    pub(super) fn refusal(&self, id: WorkerId) -> Option<Refusal> {
        if let Some(why) = &self.convicted {
            return Some(Refusal::Denied(format!(
                "worker {id} is quarantined: {why}"
            )));
        }
        self.quarantined.then(|| {
            Refusal::Denied(format!(
                "worker {id} is quarantined after {} invalid results",
                self.bad_results
            ))
        })
    }
}

impl Scheduler {
    /// A worker's public id, as listed.
    pub fn worker_id(&self, n: u64) -> WorkerId {
        WorkerId {
            epoch: self.epoch,
            n,
        }
    }

    /// The credential a worker quotes in its calls: the public id and its secret. Only
    /// `Register`'s reply carries it.
    pub fn worker_credential(&self, n: u64) -> Option<WorkerCredential> {
        let w = self.workers.get(&n)?;
        Some(WorkerCredential {
            id: self.worker_id(n),
            secret: w.secret.clone(),
        })
    }

    /// Looks up a worker by the credential it quotes and marks it seen. A credential with a
    /// wrong secret is as unknown as one never issued, so guessing reveals nothing.
    pub fn touch_worker(&mut self, cred: &WorkerCredential, now: Instant) -> Result<u64, Refusal> {
        use subtle::ConstantTimeEq;
        let unknown = || {
            Refusal::UnknownWorker(format!(
                "unknown worker {} (the coordinator may have restarted): register again",
                cred.id
            ))
        };
        if cred.id.epoch != self.epoch {
            return Err(unknown());
        }
        let n = cred.id.n;
        let w = self.workers.get_mut(&n).ok_or_else(unknown)?;
        if !bool::from(w.secret.as_bytes().ct_eq(cred.secret.as_bytes())) {
            return Err(unknown());
        }
        w.last_seen = now;
        w.gone = false;
        match w.refusal(cred.id) {
            Some(r) => Err(r),
            None => Ok(n),
        }
    }

    /// Registers a worker and returns its number. `secret` must be unguessable (the service
    /// draws it from the operating system's random source).
    pub fn register(
        &mut self,
        name: String,
        cores: u32,
        version: String,
        secret: String,
        now: Instant,
    ) -> u64 {
        let n = self.next_worker;
        self.next_worker += 1;
        self.workers.insert(
            n,
            Worker {
                secret,
                name,
                cores,
                version,
                last_seen: now,
                units_done: 0,
                samples_done: 0,
                bad_results: 0,
                gone: false,
                quarantined: false,
                convicted: None,
                disputes: BTreeSet::new(),
                audits_passed: 0,
                jobs: BTreeSet::new(),
                host: String::new(),
                rate: Rate::default(),
                caps: Capabilities::default(),
                draining: false,
                log_bucket: Default::default(),
            },
        );
        n
    }

    /// Whether `host` may register one more worker: it has fewer than
    /// [`Scheduler::max_workers_per_host`] live registrations. An unknown host (no address)
    /// is not counted.
    pub fn host_may_register(&self, host: &str, now: Instant) -> Result<(), Refusal> {
        if host.is_empty() {
            return Ok(());
        }
        let live = self
            .workers
            .values()
            .filter(|x| x.host == host && x.alive(now, self.policy.lease_time) && !x.quarantined)
            .count();
        if live >= self.policy.max_workers_per_host {
            return Err(Refusal::Exhausted(format!(
                "{host} has {live} live worker registrations, the most one host may have \
                 (tessera coordinator --max-workers-per-host)"
            )));
        }
        Ok(())
    }

    /// Counts an invalid result against worker `w`, quarantining it (and taking back its
    /// leases) once it reaches the limit.
    pub fn count_bad_result(&mut self, w: u64) {
        let id = self.worker_id(w);
        let Some(worker) = self.workers.get_mut(&w) else {
            return;
        };
        worker.bad_results += 1;
        if worker.bad_results >= self.policy.quarantine_after && !worker.quarantined {
            worker.quarantined = true;
            tracing::warn!(
                "worker {id} ({}) quarantined after {} invalid results",
                worker.name.escape_debug(),
                worker.bad_results
            );
            for lease in self.leases.values_mut() {
                if lease.worker == w && lease.active {
                    requeue(&mut self.jobs, lease);
                }
            }
        }
    }

    /// Records the address worker `w` registered from: one host's registrations are counted
    /// together ([`Scheduler::host_may_register`]) and vote once in audits.
    pub fn set_host(&mut self, w: u64, host: String) {
        if let Some(x) = self.workers.get_mut(&w) {
            x.host = host;
        }
    }

    /// Worker `w` said goodbye: it is listed as gone until it calls again.
    pub fn goodbye(&mut self, w: u64) {
        if let Some(x) = self.workers.get_mut(&w) {
            x.gone = true;
        }
    }
}
