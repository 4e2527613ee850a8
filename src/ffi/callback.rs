//! Adapter from the C noise callback to the core's `NoiseScales` trait.

use core::ffi::c_void;

use super::{sie_cloud, sie_trace_entry};
use crate::{CloudRole, NoiseScales, TraceEntry};

/// The non-NULL C function type behind `sie_noise_fn`.
pub(crate) type NoiseFunction = unsafe extern "C" fn(
    user_data: *mut c_void,
    cloud: u32,
    xyz: *const f64,
    n: usize,
    out_sigma: *mut f64,
) -> i32;

/// A registered callback and the opaque pointer handed back to it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NoiseCallback {
    pub(crate) function: NoiseFunction,
    pub(crate) user_data: *mut c_void,
}

impl NoiseScales for NoiseCallback {
    fn point_sigmas(&mut self, cloud: CloudRole, points: &[[f64; 3]], out: &mut [f64]) -> Result<(), String> {
        // The header promises 1.0 everywhere the callback does not write.
        out.fill(1.0);
        let (cloud_code, cloud_name) = match cloud {
            CloudRole::Source => (sie_cloud::Source as u32, "source"),
            CloudRole::Target => (sie_cloud::Target as u32, "target"),
        };
        let n = points.len().min(out.len());
        // SAFETY: `[[f64; 3]]` is n*3 contiguous f64s and `out` holds at least n f64s; both stay
        // borrowed for the duration of the synchronous call. The function pointer and user data
        // come from `sie_context_set_noise_callback`, whose caller vouches for them.
        let code = unsafe {
            (self.function)(
                self.user_data,
                cloud_code,
                points.as_ptr().cast::<f64>(),
                n,
                out.as_mut_ptr(),
            )
        };
        if code == 0 {
            Ok(())
        } else {
            Err(format!(
                "noise callback returned {code} for the {cloud_name} cloud ({n} points)"
            ))
        }
    }
}

/// The non-NULL C function type behind `sie_progress_fn`.
pub(crate) type ProgressFunction =
    unsafe extern "C" fn(user_data: *mut c_void, entry: *const sie_trace_entry) -> i32;

/// A registered progress callback and its user data.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ProgressCallback {
    pub(crate) function: ProgressFunction,
    pub(crate) user_data: *mut c_void,
}

impl ProgressCallback {
    /// Calls the C function with one iteration's entry; non-zero asks to cancel.
    pub(crate) fn call(&self, entry: &TraceEntry) -> i32 {
        let entry = super::results::trace_entry_of(entry);
        // SAFETY: `entry` lives for the duration of the synchronous call; the function pointer
        // and user data come from `sie_context_set_progress_callback`, whose caller vouches.
        unsafe { (self.function)(self.user_data, &entry) }
    }
}
