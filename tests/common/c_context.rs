//! An owned `sie_context` for the tests that call the C ABI as a host would.
use std::ffi::CStr;
use std::ptr::{null, null_mut};

use sie::ffi::*;

/// An owned context freed on drop.
pub struct Context(pub *mut sie_context);

impl Context {
    pub fn new() -> Self {
        let ctx = sie_context_new();
        assert!(!ctx.is_null());
        Context(ctx)
    }

    /// ICP on packed double clouds from the identity: the status, the transform in `out`.
    pub fn register(&self, source: &[[f64; 3]], target: &[[f64; 3]], out: &mut [f64; 16]) -> sie_status {
        self.register_from(source, target, None, out)
    }

    /// [`Context::register`] from `init` (row-major 4×4, or the identity).
    pub fn register_from(
        &self,
        source: &[[f64; 3]],
        target: &[[f64; 3]],
        init: Option<&[f64; 16]>,
        out: &mut [f64; 16],
    ) -> sie_status {
        // SAFETY: packed arrays of the given counts; `init` NULL or 16 doubles; `out` holds 16.
        unsafe {
            sie_context_register_d(
                self.0,
                source.as_ptr().cast(),
                source.len(),
                0,
                target.as_ptr().cast(),
                target.len(),
                0,
                init.map_or(null(), |t| t.as_ptr()),
                out.as_mut_ptr(),
            )
        }
    }

    /// Correspondence registration of packed double pairs from the identity: the status, the
    /// transform in `out`.
    pub fn register_pairs(
        &self,
        source: &[[f64; 3]],
        target: &[[f64; 3]],
        out: &mut [f64; 16],
    ) -> sie_status {
        // SAFETY: packed arrays of equal length; `out` holds 16 doubles.
        unsafe {
            sie_context_register_correspondences_d(
                self.0,
                source.as_ptr().cast(),
                0,
                target.as_ptr().cast(),
                0,
                source.len(),
                null(),
                out.as_mut_ptr(),
            )
        }
    }

    pub fn last_error(&self) -> String {
        // SAFETY: live context; the string is copied before the next call.
        unsafe { CStr::from_ptr(sie_context_last_error(self.0)) }
            .to_string_lossy()
            .into_owned()
    }

    pub fn summary(&self) -> sie_summary {
        let mut summary = sie_summary::default();
        // SAFETY: live context and a valid out pointer.
        assert_eq!(
            unsafe { sie_context_get_summary(self.0, &mut summary) },
            sie_status::Ok
        );
        summary
    }

    pub fn probabilities(&self, n: usize) -> Vec<f64> {
        let mut out = vec![-1.0; n];
        // SAFETY: `out` holds n doubles.
        let status = unsafe { sie_context_get_inlier_probabilities(self.0, out.as_mut_ptr(), n, null_mut()) };
        assert_eq!(status, sie_status::Ok);
        out
    }

    pub fn correspondences(&self, n: usize) -> Vec<i64> {
        let mut out = vec![-7; n];
        // SAFETY: `out` holds n entries.
        let status = unsafe { sie_context_get_correspondences(self.0, out.as_mut_ptr(), n, null_mut()) };
        assert_eq!(status, sie_status::Ok);
        out
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: created by sie_context_new, freed once.
        unsafe { sie_context_free(self.0) };
    }
}
