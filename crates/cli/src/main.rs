//! `tessera`: the command line of the tessera render farm.
//!
//! `tessera render` renders a scene locally, on every core, with no network (the default
//! way to use tessera). The farm commands run a coordinator (`tessera coordinator`) and
//! workers (`tessera worker`) and talk to a coordinator (`submit`, `status`, `cancel`,
//! `pause`, `resume`, `priority`, `logs`, `workers`, `fetch`); see the README.

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

mod args;
#[cfg(feature = "bench")]
mod bench;
mod denoise;
mod farm;
mod render;
mod terminal;

/// tessera: a distributed path-tracing render farm.
#[derive(Debug, Parser)]
#[command(
    name = "tessera",
    version,
    about,
    propagate_version = true,
    after_help = "Logging (coordinator, worker): RUST_LOG sets what is logged to stderr, e.g. \
                  RUST_LOG=debug or RUST_LOG=tessera_coordinator=debug,info (default: info).\n\
                  Shell completions: tessera completions bash|zsh|fish|elvish|powershell."
)]
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
    /// Pause a job: its leased units finish, nothing new is leased until `tessera resume`.
    Pause(farm::PauseArgs),
    /// Resume a paused job.
    Resume(farm::PauseArgs),
    /// Change a queued or running job's priority (higher runs first).
    Priority(farm::PriorityArgs),
    /// Put a failed job's failed frames back in the queue.
    Retry(farm::RetryArgs),
    /// Print the warnings and errors workers reported about a job's units.
    Logs(farm::LogsArgs),
    /// List the workers a coordinator has seen.
    Workers(farm::WorkersArgs),
    /// Download a finished job's EXR.
    Fetch(farm::FetchArgs),
    /// Write the PNG preview of an EXR file (as `render --preview` does).
    Preview(render::PreviewCommandArgs),
    /// Print a shell completion script, e.g. `tessera completions bash >
    /// /etc/bash_completion.d/tessera`, or `source <(tessera completions zsh)`.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Measure speed against error: timed renders at 4…4096 spp, relMSE against references,
    /// and a report with a log–log plot (and peers' figures, if given).
    #[cfg(feature = "bench")]
    Bench(bench::BenchArgs),
    /// Run many simulated workers against one coordinator on loopback and report its
    /// throughput, lease latency, CPU, memory and bytes written.
    #[cfg(feature = "bench")]
    Loadtest(bench::load::LoadArgs),
    /// Measure speed against error (in builds with the `bench` feature only).
    #[cfg(not(feature = "bench"))]
    #[command(disable_help_flag = true)]
    Bench {
        /// Ignored: this build has no benchmark harness.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, hide = true)]
        args: Vec<String>,
    },
    /// Load-test a coordinator (in builds with the `bench` feature only).
    #[cfg(not(feature = "bench"))]
    #[command(disable_help_flag = true)]
    Loadtest {
        /// Ignored: this build has no benchmark harness.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, hide = true)]
        args: Vec<String>,
    },
}

/// What `bench` and `loadtest` say in a build without them: how to get a build with them. Asked
/// for help, that is the help (exit 0); otherwise it is the error.
#[cfg(not(feature = "bench"))]
fn without_bench(command: &str, args: &[String]) -> anyhow::Result<()> {
    let hint = format!(
        "`tessera {command}` is in builds with the benchmark harness only; build one with \
         `cargo build --release -p tessera-cli --features bench` (bench/speed-vs-error.sh does)"
    );
    if args.iter().any(|a| a == "--help" || a == "-h") {
        outln!("{hint}");
        return Ok(());
    }
    Err(anyhow::anyhow!(
        "this tessera was built without the benchmark harness: {hint}"
    ))
}

/// mimalloc rather than glibc's malloc: a coordinator that merged a large frame's tiles (tens
/// of thousands of mid-sized vectors) kept most of that memory after the job ended under glibc,
/// which returns freed memory from its arenas only at their top (docs/farm.md, "Memory").
/// Built without transparent huge pages (the workspace's `no_thp` feature): each fresh huge
/// page is zeroed whole, which was most of a coordinator's CPU time on small jobs.
#[cfg(feature = "mimalloc")]
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> ExitCode {
    forget_empty_settings();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
        Command::Coordinator(args) => farm::coordinator(args),
        Command::Worker(args) => farm::worker(args),
        Command::Submit(args) => farm::submit(args),
        Command::Status(args) => farm::status(args),
        Command::Cancel(args) => farm::cancel(args),
        Command::Pause(args) => farm::pause(args, true),
        Command::Resume(args) => farm::pause(args, false),
        Command::Priority(args) => farm::priority(args),
        Command::Retry(args) => farm::retry(args),
        Command::Logs(args) => farm::logs(args),
        Command::Workers(args) => farm::workers(args),
        Command::Fetch(args) => farm::fetch(args),
        Command::Preview(args) => render::preview(args),
        Command::Completions { shell } => {
            use clap::CommandFactory as _;
            let mut out = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "tessera", &mut out);
            use std::io::Write as _;
            std::io::stdout()
                .write_all(&out)
                .map_err(anyhow::Error::from)
        }
        #[cfg(feature = "bench")]
        Command::Bench(args) => bench::run(args),
        #[cfg(feature = "bench")]
        Command::Loadtest(args) => bench::load::run(args),
        #[cfg(not(feature = "bench"))]
        Command::Bench { args } => without_bench("bench", &args),
        #[cfg(not(feature = "bench"))]
        Command::Loadtest { args } => without_bench("loadtest", &args),
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

/// Removes every `TESSERA_*` environment variable whose value is empty (or blank), before
/// clap reads them.
///
/// An empty variable means "not set" to people and to the tools that pass settings on:
/// docker compose turns `${TESSERA_WORKER_THREADS:-}` into `TESSERA_WORKER_THREADS=` when the
/// host has none, and clap would then refuse `--threads ''` and crash-loop every worker.
/// Runs first in `main`, while the process has one thread.
fn forget_empty_settings() {
    for (key, value) in std::env::vars_os() {
        let ours = key.to_str().is_some_and(|k| k.starts_with("TESSERA_"));
        let blank = value.to_str().is_some_and(|v| v.trim().is_empty());
        if ours && blank {
            std::env::remove_var(key);
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
