//! Progress of a long part on stderr.
use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use crate::report::duration;

/// Progress on stderr: one line per finished unit, and a live counter on a terminal.
pub struct Progress {
    what: String,
    total: usize,
    done: AtomicUsize,
    start: Instant,
    live: bool,
    /// Serialises the stderr lines of several workers.
    lock: Mutex<()>,
}

impl Progress {
    pub fn new(what: &str, total: usize) -> Self {
        Progress {
            what: what.into(),
            total,
            done: AtomicUsize::new(0),
            start: Instant::now(),
            live: std::io::stderr().is_terminal(),
            lock: Mutex::new(()),
        }
    }

    /// One more unit done; `note` is printed with the count, elapsed time and ETA.
    pub fn step(&self, note: &str) {
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        let elapsed = self.start.elapsed().as_secs_f64();
        let eta = elapsed / done as f64 * (self.total - done) as f64;
        let _guard = self.lock.lock();
        eprintln!(
            "[{}] {done}/{} {note} — elapsed {}, ETA {}",
            self.what,
            self.total,
            duration(elapsed),
            duration(eta)
        );
    }

    pub fn tick(&self, note: &str, done: usize, total: usize) {
        if self.live {
            let _guard = self.lock.lock();
            eprint!("\r[{}] {note}: {done}/{total} instances   \r", self.what);
        }
    }
}
