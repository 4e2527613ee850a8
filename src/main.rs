//! `sie` command-line tool: `sie register SOURCE TARGET` registers two scan files with SIE and
//! reports the transform; `sie demo` does the same on a built-in synthetic scene.
//!
//! Every failure is one line `sie: <message>` on stderr and a documented exit code (see
//! `cli::exit`); a panic would be a bug, and is reported the same way.
mod cli;

use std::panic;
use std::process::ExitCode;

use clap::Parser;

use cli::args::{Cli, Command};
use cli::exit;

fn main() -> ExitCode {
    // Replaces the default hook's multi-line report (and backtrace hint) with one line.
    panic::set_hook(Box::new(|info| {
        let message = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        let location = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!("sie: internal error: {message}{location} (this is a bug; please report it)");
    }));
    let cli = Cli::parse();
    let outcome = panic::catch_unwind(|| match &cli.command {
        Command::Register(args) => cli::register::run(args),
        Command::Demo(args) => cli::demo::run(args),
        Command::Odometry(args) => cli::odometry::run(args),
    });
    match outcome {
        Ok(Ok(code)) => ExitCode::from(code),
        Ok(Err(error)) => {
            eprintln!("sie: {error}");
            ExitCode::from(exit::ERROR)
        }
        Err(_) => ExitCode::from(exit::INTERNAL),
    }
}
