//! A worker's result, from its arrival to its merge: the policy between the gRPC handler
//! (which only reads the wire) and the scheduler (which merges). In order:
//!
//! 1. A guided unit's training tree, up to tens of MiB, is decoded off the async threads,
//!    and only for a registered worker.
//! 2. Under the scheduler's lock: a result that arrives while too many merged sums wait for
//!    the store is deferred (the worker retries; [`Scheduler::defer_result`]) before it costs
//!    its checks; then its sums are decoded and checked, and merged.
//! 3. A tile whose sums left memory between batches (a large job's open tile) is read back
//!    from the store outside the lock and the merge tried again; a read that raced a
//!    checkpoint is read again, three times at most.
//! 4. Once merged: the referee's pending work, the merge's time, and a finished job's EXR.
//!
//! [`Scheduler::defer_result`]: crate::scheduler::Scheduler::defer_result

use std::sync::Arc;
use std::time::Instant;

use tessera_proto::ids::{JobId, LeaseId, WorkerCredential};
use tessera_proto::v1 as pb;
use tessera_render::guide::SdTree;
use tessera_render::{PixelRect, TileSums};
use tracing::warn;

use crate::error::Refusal;
use crate::job::Unit;
use crate::output::finish_job;
use crate::scheduler::{Merged, UnitResult};
use crate::shared::Shared;
use crate::store::Op;

/// Reads back a tile's sums this many times at most for one result.
const MAX_READS: u32 = 3;

/// A result as it arrived: who sent it, for which lease and unit, and what it holds.
pub(crate) struct Arrival {
    /// The sender.
    pub cred: WorkerCredential,
    /// The unit's job.
    pub job: JobId,
    /// The lease it answers.
    pub lease: LeaseId,
    /// The unit.
    pub unit: Unit,
    /// Its sums (and a guided unit's training tree), as sent.
    pub result: Option<pb::TileResult>,
}

/// What became of a result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// Merged, or held for its audit (the worker is told merged either way: it must not learn
    /// which of its units are audited).
    Merged,
    /// The unit was merged already, from another copy.
    Duplicate,
    /// Not wanted any more (its job ended, or its lease was taken back).
    Discarded,
}

/// Takes `arrival` to its merge (see the module's steps).
pub(crate) async fn ingest(shared: &Arc<Shared>, arrival: Arrival) -> Result<Outcome, Refusal> {
    let arrived = Instant::now();
    let Arrival {
        cred,
        job,
        lease,
        unit,
        mut result,
    } = arrival;
    let train = decode_train(shared, &cred, &mut result).await?;
    let mut pending = Pending {
        result,
        train,
        decoded: None,
    };
    let mut read_back = None;
    let mut reads = 0;
    let (finished, new) = loop {
        let here = Here {
            cred: &cred,
            job,
            lease,
            unit,
        };
        match merge_step(shared, here, &mut pending, read_back.take())? {
            Step::Merged { finished, new } => break (finished, new),
            Step::Answer(outcome) => return Ok(outcome),
            Step::ReadBack(rect) => {
                if reads == MAX_READS {
                    return Err(Refusal::Unavailable(format!(
                        "{job} tile {}: its sums could not be read back; retry",
                        unit.tile
                    )));
                }
                reads += 1;
                read_back = Some(read_tile(shared, job, unit.tile, rect).await?);
            }
        }
    };
    crate::referee::spawn_pending(shared);
    if new {
        shared.metrics.merge.observe(arrived.elapsed());
    }
    if finished {
        tokio::spawn(finish_job(shared.clone(), job));
    }
    shared.bump_changed();
    Ok(Outcome::Merged)
}

/// Where a result goes: its sender, lease and unit.
#[derive(Clone, Copy)]
struct Here<'a> {
    cred: &'a WorkerCredential,
    job: JobId,
    lease: LeaseId,
    unit: Unit,
}

/// A result not merged yet: as sent, or decoded once (kept across read-backs).
struct Pending {
    result: Option<pb::TileResult>,
    train: Option<Result<SdTree, Refusal>>,
    decoded: Option<UnitResult>,
}

impl Pending {
    /// The sums and training tree, decoded and checked once.
    fn take(&mut self) -> Result<UnitResult, Refusal> {
        if let Some(d) = self.decoded.take() {
            return Ok(d);
        }
        let sums = self
            .result
            .take()
            .ok_or_else(|| Refusal::Invalid("request has no result".into()))
            .and_then(|r| TileSums::try_from(r).map_err(|e| Refusal::Invalid(e.to_string())))?;
        Ok(UnitResult {
            sums,
            train: self.train.take().transpose()?,
        })
    }
}

/// What one try under the lock came to.
enum Step {
    /// Merged (or held for its audit): whether its job finished, and whether it was new.
    Merged { finished: bool, new: bool },
    /// Answered without a merge.
    Answer(Outcome),
    /// Its tile must be read back from the store first.
    ReadBack(PixelRect),
}

/// A guided unit's training tree, decoded off the async threads; `None` for a unit that
/// trains none. Only a registered worker's is worth the decoding.
async fn decode_train(
    shared: &Shared,
    cred: &WorkerCredential,
    result: &mut Option<pb::TileResult>,
) -> Result<Option<Result<SdTree, Refusal>>, Refusal> {
    let bytes = result
        .as_mut()
        .map(|r| std::mem::take(&mut r.guide_train))
        .filter(|b| !b.is_empty());
    let Some(bytes) = bytes else {
        return Ok(None);
    };
    shared.scheduler().touch_worker(cred, Instant::now())?;
    let tree = tokio::task::spawn_blocking(move || SdTree::decode(&bytes))
        .await
        .map_err(|e| Refusal::Internal(e.to_string()))?;
    Ok(Some(tree.map_err(|e| {
        Refusal::Invalid(format!("guide_train: {e}"))
    })))
}

/// One try at merging under the scheduler's lock, which is let go before any await.
fn merge_step(
    shared: &Shared,
    here: Here<'_>,
    pending: &mut Pending,
    read_back: Option<TileSums>,
) -> Result<Step, Refusal> {
    let mut core = shared.scheduler();
    let now = Instant::now();
    let w = core.touch_worker(here.cred, now)?;
    if pending.decoded.is_none() && core.defer_result() {
        // Before its checks and merge, which a deferred result does not cost; the worker
        // keeps it (its lease renewed by heartbeats) until the retry.
        drop(core);
        shared.request_checkpoint();
        return Err(Refusal::Unavailable(
            "the coordinator is storing merged results; retry shortly".into(),
        ));
    }
    let sums = pending.take().inspect_err(|e| {
        core.refuse_result(w);
        warn!("result from {} refused: {e:?}", here.cred.id);
    })?;
    if let Some(back) = read_back {
        core.reload(here.job, here.unit.tile, back);
    }
    if let Some(rect) = core.needs_reload(w, here.lease, here.job, here.unit) {
        pending.decoded = Some(sums);
        return Ok(Step::ReadBack(rect));
    }
    match core.submit(w, here.lease, here.job, here.unit, sums, now) {
        Ok(Merged::New { ops, finished }) => {
            // Acknowledged once merged in memory: the next checkpoint makes it durable, and a
            // crash before then costs its rendering again, not its bits. A guide was trained:
            // the next epoch's units are free.
            let epoch = ops.iter().any(|o| matches!(o, Op::PutGuide(..)));
            shared.queue_checkpointed(ops);
            if epoch {
                shared.bump_work();
            }
            if core.wants_checkpoint() {
                shared.request_checkpoint();
            }
            Ok(Step::Merged {
                finished,
                new: true,
            })
        }
        Ok(Merged::Duplicate) => Ok(Step::Answer(Outcome::Duplicate)),
        Ok(Merged::Held) => Ok(Step::Merged {
            finished: false,
            new: false,
        }),
        Ok(Merged::Discarded) => Ok(Step::Answer(Outcome::Discarded)),
        Err(r) => {
            warn!("result from {} refused: {r:?}", here.cred.id);
            Err(r)
        }
    }
}

/// Tile `tile` of `job`'s sums, read back from the store.
async fn read_tile(
    shared: &Shared,
    job: JobId,
    tile: u32,
    rect: PixelRect,
) -> Result<TileSums, Refusal> {
    let store = shared.store.clone();
    tokio::task::spawn_blocking(move || store.tile(job.0, tile, rect))
        .await
        .map_err(|e| Refusal::Internal(format!("reading a tile back: {e}")))?
        .map_err(|e| Refusal::Internal(format!("coordinator state store: {e}")))
}
