//! Data parallelism for matching and normals: scoped worker threads per call and fixed-size
//! chunks, so results never depend on the thread count.
//!
//! Why not a thread pool (rayon): a pool's threads exit in the background after it is dropped
//! and leave per-thread state (and, for the calling thread, an epoch record that is never
//! freed), which memory checkers report as leaks in a host process. Scoped threads are joined
//! before the call returns; spawning two or three per ICP iteration costs tens of
//! microseconds against milliseconds of work, and small inputs run on the caller's thread.
use std::num::NonZeroUsize;
use std::sync::Mutex;

/// Work items per chunk of [`Workers::for_each_chunk_mut`]; fixed so that chunking (and any
/// per-chunk reduction order) is the same for 1 or N threads. Matching and normals, whose
/// results do not depend on the chunking, use smaller pieces (`for_each_chunk_of`) so that a
/// few thousand items still split evenly over two threads.
pub const CHUNK: usize = 1024;

/// How many threads a registration may use (the caller's thread included).
pub struct Workers {
    threads: usize,
}

impl Workers {
    /// `threads`: 0 = one per core, 1 = caller's thread only, n = n threads.
    pub fn new(threads: usize) -> Result<Self, String> {
        let threads = match threads {
            0 => std::thread::available_parallelism().map_or(1, NonZeroUsize::get),
            n => n,
        };
        Ok(Workers { threads })
    }

    /// Calls `f(first_index, chunk)` on consecutive `CHUNK`-sized pieces of `data`, on up to
    /// `threads` threads; when the system cannot start that many, on those it could (at least
    /// the caller's), with the same result.
    pub fn for_each_chunk_mut<T: Send>(&self, data: &mut [T], f: impl Fn(usize, &mut [T]) + Sync + Send) {
        self.for_each_chunk_of(CHUNK, data, f);
    }

    /// [`Workers::for_each_chunk_mut`] with `chunk`-sized pieces: for work whose result does not
    /// depend on the chunking (no per-chunk reduction) and whose items are costly enough that a
    /// few hundred of them are worth a thread.
    pub fn for_each_chunk_of<T: Send>(
        &self,
        chunk: usize,
        data: &mut [T],
        f: impl Fn(usize, &mut [T]) + Sync + Send,
    ) {
        let chunk = chunk.max(1);
        let chunks = data.len().div_ceil(chunk);
        let threads = self.threads.min(chunks);
        if threads <= 1 {
            data.chunks_mut(chunk)
                .enumerate()
                .for_each(|(c, piece)| f(c * chunk, piece));
            return;
        }
        // Threads take the next chunk from a shared queue, so uneven chunks balance out.
        let queue = Mutex::new(data.chunks_mut(chunk).enumerate());
        let work = || {
            loop {
                let next = queue.lock().unwrap_or_else(|e| e.into_inner()).next();
                let Some((c, piece)) = next else { break };
                f(c * chunk, piece);
            }
        };
        std::thread::scope(|scope| {
            // A thread the system refuses (no memory for its stack, a process or thread limit)
            // is not needed: the threads that did start, and this one, take its chunks.
            let helpers: Vec<_> = (1..threads)
                .map_while(|_| std::thread::Builder::new().spawn_scoped(scope, work).ok())
                .collect();
            work();
            // Join explicitly: `scope` alone returns once the closures are done, while the OS
            // threads may still be tearing down (valgrind then sees their TLS at a host's exit).
            for helper in helpers {
                if let Err(panic) = helper.join() {
                    std::panic::resume_unwind(panic);
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_element_is_visited_once_with_its_index_for_any_thread_count() {
        for threads in [1, 2, 3, 8] {
            let workers = Workers::new(threads).unwrap();
            let mut data = vec![0usize; 3 * CHUNK + 17];
            workers.for_each_chunk_mut(&mut data, |start, chunk| {
                for (k, v) in chunk.iter_mut().enumerate() {
                    *v += start + k + 1;
                }
            });
            assert!(
                data.iter().enumerate().all(|(i, v)| *v == i + 1),
                "{threads} threads"
            );
            for chunk in [0, 1, 7, 256] {
                let mut data = vec![0usize; 1000];
                workers.for_each_chunk_of(chunk, &mut data, |start, piece| {
                    for (k, v) in piece.iter_mut().enumerate() {
                        *v += start + k + 1;
                    }
                });
                assert!(
                    data.iter().enumerate().all(|(i, v)| *v == i + 1),
                    "{threads} threads, chunks of {chunk}"
                );
            }
        }
    }
}
