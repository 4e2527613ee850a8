//! The `sie` command-line tool: argument parsing, the `register`, `demo` and `odometry` commands, their
//! reports (text, JSON, the histogram plot) and the live progress on stderr.
//!
//! Everything here runs on the same core as the C ABI (`register_clouds`); none of it is part
//! of the library.

pub mod args;
pub mod demo;
pub mod glyphs;
pub mod numbers;
pub mod odometry;
pub mod plot;
pub mod progress;
pub mod register;
pub mod report;

use std::fmt::Display;

/// Exit codes, also listed in `sie --help`.
pub mod exit {
    /// Registered and converged.
    pub const CONVERGED: u8 = 0;
    /// Registered, but stopped at the iteration limit or on a degenerate problem; every
    /// requested output was still written.
    pub const NOT_CONVERGED: u8 = 1;
    /// Registered and converged, but the verdict is not GOOD (doubtful or unsupported): check
    /// the pose before using it; every requested output was still written. SIE cost only: a
    /// baseline cost has no fitted noise model for the verdict to rest on.
    pub const NOT_GOOD: u8 = 3;
    /// Bad usage, an unreadable or malformed input file, input the registration rejects, or
    /// an output that could not be written.
    pub const ERROR: u8 = 2;
    /// A bug: an internal panic (reported on one line, please file it).
    pub const INTERNAL: u8 = 70;
    /// Cancelled with Ctrl-C; the transform reached so far was still reported.
    pub const CANCELLED: u8 = 130;
}

/// Text for `--help`, kept next to the codes it describes.
pub const EXIT_CODES_HELP: &str = "\
Exit codes:
  0    registered and converged
  1    registered but not converged (iteration limit or degenerate problem); outputs still written
  2    usage error, unreadable or malformed input, input rejected by the registration, or an
       output that could not be written (one line `sie: <message>` on stderr)
  3    registered and converged, but SIE's verdict is not good (doubtful: check the pose or
       retry from another guess; unsupported: do not use it); outputs still written
  70   internal error (a bug; please report the message)
  130  cancelled with Ctrl-C; the transform reached so far is still reported";

/// A failure reported as one line `sie: <message>` with exit code [`exit::ERROR`].
#[derive(Debug)]
pub struct CliError(pub String);

impl CliError {
    pub fn new(message: impl Display) -> Self {
        // Library messages can span lines; the user gets exactly one.
        let one_line = message
            .to_string()
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ");
        CliError(one_line)
    }
}

impl Display for CliError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
