//! `tessera`: the command line of the tessera render farm.
//!
//! `tessera render` renders a scene locally, on every core, with no network.

use std::process::ExitCode;

use clap::Parser;

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
