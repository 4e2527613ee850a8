//! Data parallelism for matching and normals: a rayon pool per registration (or none), and
//! fixed-size chunks so results never depend on the thread count.
use rayon::prelude::*;

/// Work items per chunk; fixed so that chunking (and any per-chunk reduction order) is the
/// same for 1 or N threads.
pub const CHUNK: usize = 4096;

/// Worker threads for one registration. `None` runs everything on the caller's thread.
pub struct Workers {
    pool: Option<rayon::ThreadPool>,
}

impl Workers {
    /// `threads`: 0 = one per core, 1 = caller's thread only, n = n workers.
    pub fn new(threads: usize) -> Result<Self, String> {
        if threads == 1 {
            return Ok(Workers { pool: None });
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("sie-worker-{i}"))
            .build()
            .map(|pool| Workers { pool: Some(pool) })
            .map_err(|e| format!("could not start worker threads: {e}"))
    }

    /// Calls `f(first_index, chunk)` on consecutive `CHUNK`-sized pieces of `data`.
    pub fn for_each_chunk_mut<T: Send>(&self, data: &mut [T], f: impl Fn(usize, &mut [T]) + Sync + Send) {
        match &self.pool {
            None => data
                .chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(c, chunk)| f(c * CHUNK, chunk)),
            Some(pool) => pool.install(|| {
                data.par_chunks_mut(CHUNK)
                    .enumerate()
                    .for_each(|(c, chunk)| f(c * CHUNK, chunk))
            }),
        }
    }
}
