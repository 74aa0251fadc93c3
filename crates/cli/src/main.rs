//! `tessera`: the command line of the tessera render farm.
//!
//! `tessera render` renders a scene locally, on every core, with no network (the default
//! way to use tessera). The farm commands run a coordinator (`tessera coordinator`) and
//! workers (`tessera worker`) and talk to a coordinator (`submit`, `status`, `cancel`,
//! `workers`, `fetch`); see the README.

use std::process::ExitCode;

use clap::Parser;

mod bench;
mod farm;
mod render;

/// tessera: a distributed path-tracing render farm.
#[derive(Debug, Parser)]
#[command(name = "tessera", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Render a scene on this machine (no network) and write an OpenEXR file.
    Render(render::RenderArgs),
    /// Run a coordinator: accept jobs and lease their work units to workers.
    Coordinator(farm::CoordinatorArgs),
    /// Run a worker: lease work units from a coordinator and render them on every core.
    Worker(farm::WorkerArgs),
    /// Submit a scene to a coordinator (prints the job id, or follows it with --wait).
    Submit(farm::SubmitArgs),
    /// Show one job, or list every job.
    Status(farm::StatusArgs),
    /// Cancel a job.
    Cancel(farm::CancelArgs),
    /// List the workers a coordinator has seen.
    Workers(farm::WorkersArgs),
    /// Download a finished job's EXR.
    Fetch(farm::FetchArgs),
    /// Measure speed against error: timed renders at 4…4096 spp, relMSE against references,
    /// and a report with a log–log plot (and peers' figures, if given).
    Bench(bench::BenchArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
        Command::Coordinator(args) => farm::coordinator(args),
        Command::Worker(args) => farm::worker(args),
        Command::Submit(args) => farm::submit(args),
        Command::Status(args) => farm::status(args),
        Command::Cancel(args) => farm::cancel(args),
        Command::Workers(args) => farm::workers(args),
        Command::Fetch(args) => farm::fetch(args),
        Command::Bench(args) => bench::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
