//! Live feedback on stderr during a registration (through the core's per-iteration observer)
//! and Ctrl-C handling.
//!
//! * On a terminal, one status line is redrawn in place (at most 10 times a second).
//! * `--trace` prints one table row per iteration instead, terminal or not.
//! * Ctrl-C during the registration stops it after the current iteration (the transform reached
//!   so far is still reported); before or after that, or pressed twice, it exits at once.
use std::io::{IsTerminal, Write};
use std::ops::ControlFlow;
use std::sync::Once;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::{Duration, Instant};

use sie::TraceEntry;

use super::exit;
use super::report::significant;

/// Ctrl-C state: not registering (exit at once), registering, cancel requested.
const IDLE: u8 = 0;
const REGISTERING: u8 = 1;
const CANCEL_REQUESTED: u8 = 2;
static INTERRUPT_STATE: AtomicU8 = AtomicU8::new(IDLE);

/// Redraws faster than this are skipped: they only cost terminal time.
const REDRAW_INTERVAL: Duration = Duration::from_millis(100);

/// Installs the Ctrl-C handler once per process. Without one (the OS refused), Ctrl-C simply
/// ends the process as usual.
pub fn install_interrupt_handler() {
    static INSTALL: Once = Once::new();
    INSTALL.call_once(|| {
        let _ = ctrlc::set_handler(|| {
            if INTERRUPT_STATE
                .compare_exchange(REGISTERING, CANCEL_REQUESTED, Ordering::SeqCst, Ordering::SeqCst)
                .is_ok()
            {
                eprintln!("\nsie: interrupted; stopping after this iteration (Ctrl-C again quits at once)");
            } else {
                std::process::exit(exit::CANCELLED.into());
            }
        });
    });
}

/// Marks the registration as running (Ctrl-C cancels it) until dropped.
pub struct InterruptScope;

impl InterruptScope {
    pub fn enter() -> Self {
        INTERRUPT_STATE.store(REGISTERING, Ordering::SeqCst);
        InterruptScope
    }
}

impl Drop for InterruptScope {
    fn drop(&mut self) {
        INTERRUPT_STATE.store(IDLE, Ordering::SeqCst);
    }
}

fn cancel_requested() -> bool {
    INTERRUPT_STATE.load(Ordering::SeqCst) == CANCEL_REQUESTED
}

/// What to show per iteration.
pub struct Progress {
    status_line: bool,
    max_iterations: u32,
    trace: bool,
    last_draw: Option<Instant>,
    line_shown: bool,
}

/// Header of the `--trace` table; columns match [`trace_line`].
pub const TRACE_HEADER: &str = "iter  phase          sigma           beta       k  inliers           rmse       d_trans   d_rot [deg]   matches";

/// One `--trace` row.
pub fn trace_line(e: &TraceEntry) -> String {
    format!(
        "{:>4}  {:<6} {:>14} {:>14} {:>7.3} {:>8.4} {:>14} {:>13} {:>13} {:>9}",
        e.iteration,
        if e.annealing { "anneal" } else { "final" },
        significant(e.sigma),
        significant(e.beta),
        e.penalty,
        e.inlier_fraction,
        significant(e.rmse),
        format!("{:.3e}", e.translation_change),
        format!("{:.3e}", e.rotation_change.to_degrees()),
        e.correspondences
    )
}

impl Progress {
    /// `trace`: print every iteration as a table row; `quiet`: no status line.
    pub fn new(trace: bool, quiet: bool, max_iterations: u32) -> Self {
        Progress {
            status_line: !quiet && !trace && std::io::stderr().is_terminal(),
            max_iterations,
            trace,
            last_draw: None,
            line_shown: false,
        }
    }

    /// A status line before the first iteration (reading, normals), on a terminal only.
    pub fn note(&mut self, text: &str) {
        if self.status_line {
            eprint!("\r\x1b[K{text}");
            let _ = std::io::stderr().flush();
            self.line_shown = true;
        }
    }

    /// The observer body: draw, and cancel when Ctrl-C asked for it.
    pub fn on_iteration(&mut self, entry: &TraceEntry) -> ControlFlow<()> {
        if self.trace {
            if entry.iteration == 1 {
                eprintln!("{TRACE_HEADER}");
            }
            eprintln!("{}", trace_line(entry));
        } else if self.status_line && self.last_draw.is_none_or(|t| t.elapsed() >= REDRAW_INTERVAL) {
            self.last_draw = Some(Instant::now());
            eprint!(
                "\r\x1b[Kiteration {:>4}/{}  sigma {}  beta {}  inliers {:.3}  rmse {}{}",
                entry.iteration,
                self.max_iterations,
                significant(entry.sigma),
                significant(entry.beta),
                entry.inlier_fraction,
                significant(entry.rmse),
                if entry.annealing { "  (annealing beta)" } else { "" }
            );
            let _ = std::io::stderr().flush();
            self.line_shown = true;
        }
        if cancel_requested() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }

    /// Erases the status line so the summary starts on a clean line.
    pub fn finish(&mut self) {
        if self.line_shown {
            eprint!("\r\x1b[K");
            let _ = std::io::stderr().flush();
            self.line_shown = false;
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.finish();
    }
}
