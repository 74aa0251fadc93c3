//! The gRPC handlers, thin adapters over the scheduler: decode and check each request (the
//! wire's strings become typed ids and settings here, through `tessera_proto`'s conversions),
//! call into the [`Scheduler`](crate::scheduler::Scheduler) under its lock, and wait for the
//! store before replying where durability matters. Reads answer with the scheduler's views
//! ([`crate::scheduler::JobView`]), which the dashboard serialises too.
//!
//! - [`jobs`]: `tessera.v1.Jobs`, the clients' service (submit, watch, fetch, cancel, assets).
//! - [`workers`]: `tessera.v1.Workers`, the workers' service (register, lease, results).

mod jobs;
use jobs::list_page;
mod workers;

use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tessera_proto::ids::{BadId, JobId, LeaseId, WorkerCredential};
use tessera_proto::v1 as pb;
use tessera_proto::view::{JobState, JobView, WorkerView};
use tessera_render::TileSums;
use tokio_stream::Stream;
use tonic::Status;

use crate::assets::AssetError;
use crate::auth::Caller;
use crate::config::{MAX_CONCURRENT_PARSES, MAX_LEASES_PER_CALL};
use crate::error::{truncate, CommitError};
use crate::shared::Shared;

/// Both services over the same shared state.
#[derive(Clone)]
pub struct Service {
    pub(crate) shared: Arc<Shared>,
    /// Permits to parse a submitted scene ([`MAX_CONCURRENT_PARSES`]).
    parses: Arc<tokio::sync::Semaphore>,
    /// Parses running now, and the most that ever ran at once.
    parsing: Arc<(AtomicUsize, AtomicUsize)>,
}

type Stream_<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

pub(crate) fn internal(e: CommitError) -> Status {
    Status::internal(format!("coordinator state store: {e}"))
}

pub(crate) fn job_id(s: &str) -> Result<JobId, Status> {
    s.parse()
        .map_err(|e: BadId| Status::invalid_argument(e.to_string()))
}

/// Who made a call: the user its token names, or, with no tokens configured, anyone, who may
/// do anything (the farm is open).
fn caller<T>(request: &tonic::Request<T>) -> Caller {
    request
        .extensions()
        .get::<Caller>()
        .cloned()
        .unwrap_or_else(Caller::anyone)
}

/// Refuses `caller` changing job `id` (`verb` it) unless it is theirs or they are an admin;
/// an unknown job passes, for the verb to answer NOT_FOUND.
fn may_change(
    core: &crate::scheduler::Scheduler,
    id: JobId,
    caller: &Caller,
    verb: &str,
) -> Result<(), Status> {
    match core.submitter(id) {
        Some(by) => caller
            .may_change(&id.to_string(), by, verb)
            .map_err(Status::permission_denied),
        None => Ok(()),
    }
}

/// The credential a worker call quotes. A malformed one is as unknown as a wrong one, and
/// gets the same answer (register again).
pub(crate) fn credential(s: &str) -> Result<WorkerCredential, Status> {
    s.parse().map_err(|e: BadId| {
        tessera_proto::reason::unknown_worker(format!(
            "unknown worker {:?} (the coordinator may have restarted): register again",
            e.text
        ))
    })
}

/// The lease ids a worker call lists: those that parse, and those that do not (which no
/// lease of this coordinator's can be).
fn lease_ids(ids: &[String]) -> Result<(Vec<LeaseId>, Vec<String>), Status> {
    if ids.len() > MAX_LEASES_PER_CALL {
        return Err(Status::invalid_argument(format!(
            "the call lists {} leases; at most {MAX_LEASES_PER_CALL}",
            ids.len()
        )));
    }
    let mut good = Vec::with_capacity(ids.len());
    let mut bad = Vec::new();
    for id in ids {
        match id.parse() {
            Ok(l) => good.push(l),
            Err(_) => bad.push(truncate(id)),
        }
    }
    Ok((good, bad))
}

/// Converts a result from the wire, checking only what can be checked without the job (the
/// rest is [`crate::scheduler::Scheduler::submit`]'s). Public for the fuzz target.
pub fn decode_result(r: pb::TileResult) -> Result<TileSums, Status> {
    TileSums::try_from(r).map_err(|e| Status::invalid_argument(e.to_string()))
}

impl Service {
    /// Both services over `shared`.
    pub(crate) fn new(shared: Arc<Shared>) -> Self {
        Self {
            shared,
            parses: Arc::new(tokio::sync::Semaphore::new(MAX_CONCURRENT_PARSES)),
            parsing: Arc::default(),
        }
    }

    /// The most scene parses that have run at once.
    pub(crate) fn peak_parses(&self) -> usize {
        self.parsing.1.load(Ordering::SeqCst)
    }

    /// The view of job `id` (one job, one frame, or a frame range), or why there is none.
    pub(crate) fn job_view(&self, id: JobId) -> Result<JobView, Status> {
        self.shared
            .scheduler()
            .job_view(id, Instant::now())
            .ok_or_else(|| Status::not_found(format!("unknown job {id}")))
    }

    /// A page of the job listing (`page`, `size`: [`list_page`]'s), and where the next page
    /// starts; what `ListJobs` and `/api/jobs` answer.
    pub(crate) fn job_page(
        &self,
        page: &str,
        size: u32,
    ) -> Result<(Vec<JobView>, Option<usize>), Status> {
        let (offset, size) = list_page(page, size)?;
        Ok(self
            .shared
            .scheduler()
            .job_page(Instant::now(), offset, size))
    }

    /// Every worker the coordinator has seen; what `ListWorkers` and `/api/workers` answer.
    pub(crate) fn worker_views(&self) -> Vec<WorkerView> {
        self.shared.scheduler().worker_views(Instant::now())
    }

    /// The finished EXR of job `id` (of its frame `frame`, for a frame range): its name and
    /// bytes, or why there is none. What `tessera fetch` and the dashboard's download get.
    pub(crate) async fn read_output(
        &self,
        id: JobId,
        frame: Option<u32>,
    ) -> Result<(String, Vec<u8>), Status> {
        let v = self.job_view(id)?;
        let v = match (frame, v.frames.is_empty()) {
            (None, false) => {
                return Err(Status::failed_precondition(format!(
                    "{id} is a range of {} frames: fetch them one at a time by frame",
                    v.frames.len()
                )))
            }
            (Some(f), false) => {
                let Some(one) = v.frames.iter().find(|x| x.frame == f) else {
                    let r = v.frame_range.map_or(String::new(), |r| r.to_string());
                    return Err(Status::not_found(format!(
                        "{id} renders frames {r}, which do not include frame {f}"
                    )));
                };
                self.job_view(one.job_id)?
            }
            (Some(f), true) if v.settings.frame != Some(f) => {
                return Err(Status::not_found(format!("{id} does not render frame {f}")));
            }
            _ => v,
        };
        if v.state != JobState::Done {
            // A job that ended without an image never will have one: say so, not "not ready".
            let why = match v.state {
                JobState::Cancelled => "it was cancelled, so it has no EXR".to_string(),
                JobState::Failed => format!("it has no EXR: {}", v.error),
                _ => "its EXR is not ready".to_string(),
            };
            return Err(Status::failed_precondition(format!(
                "{} is {} ({}/{} units): {why}",
                v.job_id,
                v.state.name(),
                v.units_done,
                v.units_total
            )));
        }
        let path = self.shared.config.output_path(&v.output);
        let data = tokio::fs::read(&path)
            .await
            .map_err(|e| Status::not_found(format!("{}'s output {}: {e}", v.job_id, v.output)))?;
        Ok((v.output, data))
    }
}

/// The gRPC status for an asset store error.
pub(crate) fn asset_status(e: AssetError) -> Status {
    match e {
        AssetError::Invalid(m) => Status::invalid_argument(m),
        AssetError::Limit(m) => Status::resource_exhausted(m),
        AssetError::Missing(m) => Status::not_found(m),
        e @ AssetError::Io { .. } => Status::internal(e.to_string()),
    }
}
