//! `tessera fetch`: a finished job's EXR (or a frame range's, one file a frame).

use std::path::PathBuf;

use super::{check_frames_dir, connect, done, download, download_frames, follow_to_end, rpc_error};
use crate::args::{check_extension, check_output_dir};
use crate::farm::{runtime, CoordinatorUrl};
use anyhow::Result;
use tessera_proto::v1 as pb;

/// Arguments of `tessera fetch`.
#[derive(Debug, clap::Args)]
pub struct FetchArgs {
    /// Job id.
    job: String,
    #[command(flatten)]
    url: CoordinatorUrl,
    /// Where to save the EXR (default: the job's output name, here, as `submit --wait`); for
    /// a frame-range job without `--frame`, the directory every finished frame's EXR goes to
    /// (under its NAME.####.exr; default: here).
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// One frame of a frame-range job.
    #[arg(long)]
    frame: Option<u32>,
    /// Wait for the job to finish first.
    #[arg(long)]
    wait: bool,
    #[command(flatten)]
    preview: crate::args::PreviewArgs,
}

/// Runs `tessera fetch`.
pub fn fetch(args: FetchArgs) -> Result<()> {
    // A name that can only be a file is checked before anything is asked of the coordinator;
    // one that may be a frame range's directory once the job says what it is.
    let maybe_dir = args
        .output
        .as_ref()
        .is_none_or(|o| args.frame.is_none() && (o.is_dir() || o.extension().is_none()));
    if let (false, Some(o)) = (maybe_dir, &args.output) {
        check_extension("--output", o, "exr")?;
        check_output_dir(o)?;
    }
    args.preview.check()?;
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let s = if args.wait {
            follow_to_end(&mut client, &url, &args.job).await?
        } else {
            client
                .get_job(pb::GetJobRequest {
                    job_id: args.job.clone(),
                })
                .await
                .map_err(|e| rpc_error(&url, &args.job, e))?
                .into_inner()
        };
        // A whole frame range goes into a directory; one frame, or a one-frame job, to a file.
        if !s.frames.is_empty() && args.frame.is_none() {
            let dir = args.output.clone().unwrap_or_else(|| PathBuf::from("."));
            check_frames_dir(&dir)?;
            return download_frames(&mut client, &url, &s, &dir).await;
        }
        // One frame of a range is saved under that frame's own name.
        let default_name = match args.frame {
            Some(f) => s
                .frames
                .iter()
                .find(|x| x.frame == f)
                .map_or_else(|| s.output_name.clone(), |x| x.output_name.clone()),
            None => s.output_name.clone(),
        };
        if args.wait && s.frames.is_empty() {
            done(&args.job, s)?;
        }
        let out = args
            .output
            .clone()
            .unwrap_or_else(|| PathBuf::from(default_name));
        if maybe_dir {
            check_extension("--output", &out, "exr")?;
            check_output_dir(&out)?;
        }
        let bytes = download(&mut client, &url, &args.job, args.frame, &out).await?;
        outln!("{} → {} ({bytes} bytes)", args.job, out.display());
        args.preview.write_of_exr(&out)
    })
}
