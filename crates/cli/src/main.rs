//! `tessera`: the command line of the tessera render farm.
//!
//! `tessera render` renders a scene locally, on every core, with no network (the default
//! way to use tessera). The farm commands run a coordinator (`tessera coordinator`) and
//! workers (`tessera worker`) and talk to a coordinator (`submit`, `status`, `cancel`,
//! `workers`, `fetch`); see the README.

use std::process::ExitCode;

use clap::Parser;

/// `println!` that returns stdout's error instead of panicking on it.
///
/// A reader that stops early (`tessera status JOB | grep -q done`, `| head`) closes the pipe
/// while tessera still writes; `println!` would panic there and exit 101, failing the reader's
/// pipeline under `pipefail`. This hands the `BrokenPipe` back to `main`, which ends quietly.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)?;
    }};
}

/// `eprintln!` that ignores stderr's errors: progress and error lines are for a person, and a
/// closed stderr (`2>&-`) must not turn into a panic and exit code 101.
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr().lock(), $($arg)*);
    }};
}

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
        // The reader of our stdout has gone, having read what it wanted: not a failure of ours,
        // and nobody is left to tell.
        Err(e) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            errln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Whether an error comes from writing to a pipe whose reader has closed it.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}
