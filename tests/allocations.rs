//! Memory growth over repeated use, counted at the allocator.
//!
//! This binary holds one test on purpose: the count covers every thread of the process, so no
//! other test may allocate while it runs. (It replaced a resident-set check in
//! tests/hardening.rs that failed on a loaded machine: RSS moved with the neighbouring tests
//! running on parallel threads of the same binary.)
use std::alloc::{GlobalAlloc, Layout, System};
use std::ptr::{null, null_mut};
use std::sync::atomic::{AtomicUsize, Ordering};

use sie::ffi::*;
use sie::synthetic::room_scene;

/// The system allocator, counting the bytes currently allocated.
struct Counting;

static LIVE_BYTES: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let ptr = unsafe { System.alloc(layout) };
        if !ptr.is_null() {
            LIVE_BYTES.fetch_add(layout.size(), Ordering::Relaxed);
        }
        ptr
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) };
        LIVE_BYTES.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let new = unsafe { System.realloc(ptr, layout, new_size) };
        if !new.is_null() {
            LIVE_BYTES.fetch_add(new_size, Ordering::Relaxed);
            LIVE_BYTES.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        new
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Register, read every result back and estimate inliers, `times` times on one context.
fn use_context(ctx: *mut sie_context, times: usize) {
    let scene = room_scene(800, 0.01, 9);
    let n = scene.source.len();
    let mut out = [0.0; 16];
    let mut probabilities = vec![0.0; n];
    let mut correspondences = vec![0i64; n];
    let mut summary = sie_summary::default();
    let residuals: Vec<f64> = (0..600).map(|i| ((i * 37) % 101) as f64 * 1e-3 - 0.05).collect();
    let mut inliers = vec![0.0; 200];
    for _ in 0..times {
        // SAFETY: live context; packed arrays of the stated lengths; outputs sized to match.
        unsafe {
            let status = sie_context_register_d(
                ctx,
                scene.source.as_ptr().cast(),
                n,
                0,
                scene.target.as_ptr().cast(),
                scene.target.len(),
                0,
                null(),
                out.as_mut_ptr(),
            );
            assert_eq!(status, sie_status::Ok);
            assert_eq!(sie_context_get_summary(ctx, &mut summary), sie_status::Ok);
            let status = sie_context_get_inlier_probabilities(ctx, probabilities.as_mut_ptr(), n, null_mut());
            assert_eq!(status, sie_status::Ok);
            let status = sie_context_get_correspondences(ctx, correspondences.as_mut_ptr(), n, null_mut());
            assert_eq!(status, sie_status::Ok);
            let status = sie_estimate_inliers(
                ctx,
                residuals.as_ptr(),
                200,
                3,
                null(),
                0.0,
                inliers.as_mut_ptr(),
                null_mut(),
                0,
                null_mut(),
            );
            assert_eq!(status, sie_status::Ok);
        }
    }
}

#[test]
fn a_thousand_registrations_on_one_context_do_not_grow_memory() {
    let ctx = sie_context_new();
    assert!(!ctx.is_null());
    // Warm-up: one-time allocations (std's handle of this thread, lazily sized buffers).
    use_context(ctx, 50);
    let before = LIVE_BYTES.load(Ordering::Relaxed);
    use_context(ctx, 1000);
    let after = LIVE_BYTES.load(Ordering::Relaxed);
    // SAFETY: allocated above, freed once.
    unsafe { sie_context_free(ctx) };
    println!("live heap bytes before {before}, after 1000 more runs {after}");
    // A leak of a single byte per run would show as 1000.
    assert!(
        after <= before + 256,
        "the heap grew by {} bytes over 1000 registrations",
        after as isize - before as isize
    );
}
