//! `tessera pause`, `tessera resume` and `tessera priority`: a queued or running job's control,
//! through the coordinator's `UpdateJob`; and `tessera retry`, a failed one's, through
//! `RetryJob`.

use anyhow::Result;
use tessera_proto::v1 as pb;

use super::{connect, rpc_error};
use crate::farm::{runtime, CoordinatorUrl};

/// Arguments of `tessera pause` and `tessera resume`.
#[derive(Debug, clap::Args)]
pub struct PauseArgs {
    /// Job id (a frame-range job's: every frame still active).
    job: String,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Arguments of `tessera priority`.
#[derive(Debug, clap::Args)]
pub struct PriorityArgs {
    /// Job id (a frame-range job's: every frame still active).
    job: String,
    /// The new priority: higher runs first.
    #[arg(allow_negative_numbers = true)]
    priority: i32,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Arguments of `tessera retry`.
#[derive(Debug, clap::Args)]
pub struct RetryArgs {
    /// Job id (a frame-range job's: every failed frame).
    job: String,
    /// Only this frame, for a frame-range job.
    #[arg(long)]
    frame: Option<u32>,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Sends one `UpdateJob` and prints what it did.
fn update(url: &CoordinatorUrl, req: pb::UpdateJobRequest, done: &str) -> Result<()> {
    let coordinator = url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(url).await?;
        let job = req.job_id.clone();
        client
            .update_job(req)
            .await
            .map_err(|e| rpc_error(&coordinator, &job, e))?;
        outln!("{job} {done}");
        Ok(())
    })
}

/// Runs `tessera pause` (`paused`) or `tessera resume`.
pub fn pause(args: PauseArgs, paused: bool) -> Result<()> {
    let req = pb::UpdateJobRequest {
        job_id: args.job,
        paused: Some(paused),
        priority: None,
    };
    let done = if paused {
        "paused: its leased units finish, nothing new is leased until `tessera resume`"
    } else {
        "resumed"
    };
    update(&args.url, req, done)
}

/// Runs `tessera priority`.
pub fn priority(args: PriorityArgs) -> Result<()> {
    let done = format!("priority {}", args.priority);
    let req = pb::UpdateJobRequest {
        job_id: args.job,
        paused: None,
        priority: Some(args.priority),
    };
    update(&args.url, req, &done)
}

/// Runs `tessera retry`: prints each job put back, one a line.
pub fn retry(args: RetryArgs) -> Result<()> {
    let coordinator = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let r = client
            .retry_job(pb::RetryJobRequest {
                job_id: args.job.clone(),
                frame: args.frame,
            })
            .await
            .map_err(|e| rpc_error(&coordinator, &args.job, e))?
            .into_inner();
        for id in &r.job_ids {
            outln!("{id} retried: back in the queue, rendering from the start");
        }
        Ok(())
    })
}
