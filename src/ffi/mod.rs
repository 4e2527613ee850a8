//! The C ABI (`include/sie.h`, generated from this module by `tests/header.rs`).
//!
//! All `unsafe` code and raw pointers of the crate live here. Every exported function runs its
//! body inside `boundary::boundary` (panics become `SIE_STATUS_PANIC`), reads caller memory
//! into owned values first and writes outputs only after everything succeeded.
//!
//! cbindgen ignores modules, so every exported name is unique and `sie_`-prefixed.
#![allow(non_camel_case_types)]

mod boundary;
mod callback;
mod input;

// cbindgen emits functions in parse order (this file, then these modules as declared), so
// they are kept in the order the header should read: configure, register, query, estimate.
mod settings;

mod register;

mod target;

mod results;

mod estimate;

use core::ffi::{c_char, c_void};
use std::cell::{Ref, RefCell, RefMut};
use std::ffi::{CStr, CString};
use std::sync::atomic::{AtomicBool, Ordering};

use crate::registration::{RegistrationConfig, RegistrationResult};
use boundary::{FfiError, static_c_str, without_context};
use callback::{NoiseCallback, ProgressCallback};

pub use estimate::*;
pub use register::*;
pub use results::*;
pub use settings::*;
pub use target::*;

/// Status returned by every fallible function. `SIE_STATUS_OK` is 0, so `if (status)` tests
/// for failure; `sie_context_last_error` then has the details. Functions taking a status
/// (`sie_status_str`) take it as `uint32_t`.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_status {
    /// Success; outputs were written.
    Ok = 0,
    /// A required pointer argument is NULL (the message names it).
    NullArgument = 1,
    /// An argument is out of range: unknown enum value, bad stride or alignment, invalid
    /// transform, bad setting (the message names the value).
    InvalidArgument = 2,
    /// An input coordinate or value is NaN or infinite (the message names array and index).
    NonFiniteInput = 3,
    /// Not enough points (or rows) to run.
    TooFewPoints = 4,
    /// The noise callback returned non-zero or produced scales that are not finite and > 0.
    CallbackFailed = 5,
    /// No successful registration result is stored in the context.
    NoResult = 6,
    /// The output capacity is smaller than the result; nothing was written.
    BufferTooSmall = 7,
    /// The context is in use by a registration further up the stack (a call from inside its
    /// noise callback); nothing was changed.
    Busy = 8,
    /// The registration was cancelled (`sie_context_cancel` or a progress callback returning
    /// non-zero). Not a failure: the transform reached so far WAS written to
    /// `out_T_target_source` and the result stored (stop reason CANCELLED).
    Cancelled = 9,
    /// An internal error (a Rust panic) was caught; the stored result was discarded. Please
    /// report it with the message from `sie_context_last_error`.
    Panic = 100,
}

/// The robust cost used to weight correspondences (`sie_context_set_cost_function`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_cost_function {
    /// Statistical Inlier Estimation: self-tuning, no parameter (the default).
    Sie = 0,
    /// Least squares, no parameter.
    L2 = 1,
    /// Weight 1 below the threshold, 0 above. Parameter: threshold (> 0).
    TruncatedL2 = 2,
    /// Lp norm as IRLS. Parameter: p in (0, 2].
    Lp = 3,
    /// Student-t with the scale re-estimated every iteration. Parameter: degrees of freedom
    /// (> 0; 0 selects 5).
    StudentT = 4,
    /// Huber. Parameter: scale (> 0).
    Huber = 5,
    /// Cauchy. Parameter: scale (> 0).
    Cauchy = 6,
    /// Geman-McClure. Parameter: scale (> 0).
    GemanMcclure = 7,
    /// Tukey biweight. Parameter: scale (> 0).
    Tukey = 8,
}

/// The residual of cloud registration (`sie_context_set_metric`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_metric {
    /// r = T*p_source - p_target (3 components).
    PointToPoint = 0,
    /// r = n_target^T (T*p_source - p_target) (1 component; the default).
    PointToPlane = 1,
}

/// Built-in per-point noise model (`sie_context_set_noise_model`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_noise_model {
    /// Same noise everywhere (the default): residuals are not normalised.
    Constant = 0,
    /// Depth cameras: sigma ~ z^2 with z along the optical axis of each cloud's own frame.
    QuadraticDepth = 1,
}

/// Which residuals share an SIE histogram (`sie_context_set_histogram_mode`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_histogram_mode {
    /// One histogram of |r| over all residual components (the default).
    Pooled = 0,
    /// One signed histogram per residual component.
    PerColumn = 1,
}

/// Why a registration stopped (`sie_summary.stop_reason`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_stop_reason {
    /// No result.
    None = 0,
    /// The last update was below both convergence tolerances.
    Converged = 1,
    /// `max_iterations` updates were made without converging (the transform is still usable).
    IterationLimit = 2,
    /// No unique solution (no weighted correspondence, or a rank-deficient system such as
    /// collinear points); the transform is the best constrained estimate reached.
    Degenerate = 3,
    /// The caller cancelled; the transform is the one reached so far.
    Cancelled = 4,
}

/// Which cloud a noise callback call is about (its `cloud` argument).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sie_cloud {
    Source = 0,
    Target = 1,
}

/// Per-point noise callback: fill `out_sigma[i]` with the relative noise sigma (finite, > 0) of
/// point i given in `xyz` (3*n packed doubles, in that cloud's own frame, i.e. the source
/// cloud untransformed). `out_sigma` is pre-filled with 1.0. `cloud` is a `sie_cloud`.
///
/// Called once per cloud per registration (never per point), synchronously on the thread that
/// called the registration function. Return 0 on success; any other value aborts the
/// registration with `SIE_STATUS_CALLBACK_FAILED` and the value in the message. It must not
/// unwind or throw, and must not free the context; other calls on the same context from inside
/// it return `SIE_STATUS_BUSY`. The pointers are valid only during the call.
pub type sie_noise_fn = Option<
    unsafe extern "C" fn(
        user_data: *mut c_void,
        cloud: u32,
        xyz: *const f64,
        n: usize,
        out_sigma: *mut f64,
    ) -> i32,
>;

/// Progress callback: called after every iteration of a registration with that iteration's
/// trace entry (valid only during the call; `entry->transform` is the transform the update
/// reached, for a viewer that animates the registration), synchronously on the registering
/// thread. Return 0
/// to continue; any other value cancels the registration, which then returns
/// `SIE_STATUS_CANCELLED` with the transform reached so far. It must not unwind or throw; calls
/// on the same context from inside it return `SIE_STATUS_BUSY`.
pub type sie_progress_fn =
    Option<unsafe extern "C" fn(user_data: *mut c_void, entry: *const sie_trace_entry) -> i32>;

/// Summary of the last successful registration (`sie_context_get_summary`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sie_summary {
    /// Fitted inlier noise sigma per histogram (normalised units; input units with the constant
    /// noise model). Entries past the number of values are 0.
    pub sigma: [f64; 3],
    /// Final regulariser beta per histogram (same units; 0 for baseline costs).
    pub beta: [f64; 3],
    /// Final penalty k of the histogram fit (first histogram).
    pub penalty: f64,
    /// Noise shape exponent p (2 = Gaussian unless estimated).
    pub noise_shape: f64,
    /// sum P(inlier) / source_count at the returned transform (unmatched points count 0).
    pub inlier_fraction: f64,
    /// sqrt(sum P*|r|^2 / sum P), input units (plane distance for point-to-plane).
    pub rmse: f64,
    /// Number of source points (length of the per-point result arrays).
    pub source_count: u64,
    /// Number of source points matched to a target point.
    pub correspondence_count: u64,
    /// Number of updates made.
    pub iterations: u32,
    /// A `sie_stop_reason`.
    pub stop_reason: u32,
    /// Number of SIE histograms (`sie_context_get_histogram` indices; 0 for baseline costs).
    pub histogram_count: u32,
    /// True when stop_reason is SIE_STOP_REASON_CONVERGED.
    pub converged: bool,
}

/// One fitted SIE histogram model (`sie_context_get_histogram`, `sie_estimate_inliers`).
/// Residual units are normalised (input units with the constant noise model).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sie_model {
    /// Centre of the inlier model (0 for pooled |r| histograms).
    pub mu: f64,
    /// Fitted inlier sigma.
    pub sigma: f64,
    /// Model height at the peak, in counts per bin.
    pub alpha: f64,
    /// Shape exponent p of the generalised Gaussian (2 = Gaussian).
    pub shape: f64,
    /// Regulariser beta added to sigma when predicting.
    pub beta: f64,
    /// Penalty k used for the fit.
    pub penalty: f64,
    /// Histogram interval [range_lo, range_hi).
    pub range_lo: f64,
    pub range_hi: f64,
    /// Mean inlier probability of the samples inside the range.
    pub mean_inlier_probability: f64,
    /// Number of bins (length of the per-bin arrays).
    pub bins: u64,
    /// Samples that fell inside the range.
    pub samples_in_range: u64,
    /// False when no inlier peak could be fitted.
    pub peak_found: bool,
}

/// One iteration of the last registration (`sie_context_get_trace`; recorded only when
/// `sie_context_set_trace(ctx, true)` was set).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sie_trace_entry {
    /// sigma of the first histogram; the scale of baseline costs.
    pub sigma: f64,
    pub beta: f64,
    pub penalty: f64,
    /// sum P(inlier) / source points, as `sie_summary.inlier_fraction` (unmatched points count
    /// 0), over the source points this iteration matched, with this update's weights.
    pub inlier_fraction: f64,
    /// Weighted RMS residual (input units).
    pub rmse: f64,
    /// Size of this update: translation (input units) and rotation (radians).
    pub translation_change: f64,
    pub rotation_change: f64,
    pub correspondences: u64,
    /// 1-based update count.
    pub iteration: u32,
    /// True while beta is being annealed, false in the final round.
    pub annealing: bool,
    /// T_target_source reached by this update, 16 doubles ROW-major (T[4*row + col]): a
    /// viewer can move the source cloud with it every iteration.
    pub transform: [f64; 16],
}

/// Everything a context owns besides its last error message.
#[derive(Default)]
pub(crate) struct ContextState {
    pub(crate) config: RegistrationConfig,
    pub(crate) noise_callback: Option<NoiseCallback>,
    pub(crate) progress_callback: Option<ProgressCallback>,
    /// The last successful registration; cleared by a failed one and after a panic.
    pub(crate) result: Option<RegistrationResult>,
}

/// A registration context: configuration, noise callback, last result and last error.
/// Create with `sie_context_new`, free with `sie_context_free`.
///
/// A context may be used from any thread, but by one thread at a time (this includes the
/// functions taking `const sie_context*`). Distinct contexts are independent; the library has
/// no global state.
#[derive(Default)]
pub struct sie_context {
    /// In a `RefCell` so that a call made from inside the noise callback (while a registration
    /// holds the state) gets BUSY instead of creating an aliasing `&mut`.
    state: RefCell<ContextState>,
    /// Separate from `state` because every call writes it, including rejected re-entrant ones.
    last_error: RefCell<CString>,
    /// Set by `sie_context_cancel` (any thread, or a signal handler); consumed by the
    /// registration it stops. Outside `state` so that setting it never touches the RefCells.
    pub(crate) cancel_requested: AtomicBool,
}

impl sie_context {
    /// The state for reading, or BUSY while a registration on this context is running.
    pub(crate) fn state(&self) -> Result<Ref<'_, ContextState>, FfiError> {
        self.state.try_borrow().map_err(|_| FfiError::busy())
    }

    /// The state for writing, or BUSY while a registration on this context is running.
    pub(crate) fn state_mut(&self) -> Result<RefMut<'_, ContextState>, FfiError> {
        self.state.try_borrow_mut().map_err(|_| FfiError::busy())
    }

    fn set_last_error(&self, message: &str) {
        // An interior NUL would cut the message short in C; show it instead.
        let text = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
        if let Ok(mut slot) = self.last_error.try_borrow_mut() {
            *slot = text;
        }
    }

    fn clear_result(&self) {
        if let Ok(mut state) = self.state.try_borrow_mut() {
            state.result = None;
        }
    }
}

const VERSION_STRING: &CStr = static_c_str(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes());

const fn version_part(text: &str) -> u32 {
    match u32::from_str_radix(text, 10) {
        Ok(value) => value,
        Err(_) => panic!("CARGO_PKG_VERSION_* must be a number"),
    }
}

const VERSION_NUMBER: u32 = (version_part(env!("CARGO_PKG_VERSION_MAJOR")) << 16)
    | (version_part(env!("CARGO_PKG_VERSION_MINOR")) << 8)
    | version_part(env!("CARGO_PKG_VERSION_PATCH"));

/// The library version as "MAJOR.MINOR.PATCH" (static storage; never NULL). Compare with
/// SIE_VERSION_STRING to detect a header/library mismatch.
#[unsafe(no_mangle)]
pub extern "C" fn sie_version_string() -> *const c_char {
    without_context(c"".as_ptr(), || VERSION_STRING.as_ptr())
}

/// The library version as (MAJOR << 16) | (MINOR << 8) | PATCH; equals SIE_VERSION_NUMBER when
/// the header and the library match.
#[unsafe(no_mangle)]
pub extern "C" fn sie_version_number() -> u32 {
    without_context(0, || VERSION_NUMBER)
}

/// A static, NUL-terminated description of a status code; "unknown status" for values that
/// are not a `sie_status`. Never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn sie_status_str(status: u32) -> *const c_char {
    without_context(c"unknown status".as_ptr(), || {
        let text = match status {
            0 => c"ok",
            1 => c"null argument",
            2 => c"invalid argument",
            3 => c"non-finite input",
            4 => c"too few points",
            5 => c"noise callback failed",
            6 => c"no result",
            7 => c"buffer too small",
            8 => c"context busy",
            9 => c"cancelled",
            100 => c"internal panic",
            _ => c"unknown status",
        };
        text.as_ptr()
    })
}

/// Creates a context with the default configuration (SIE cost, point-to-plane, constant
/// noise). Returns NULL only if allocation fails. Free it with `sie_context_free`.
#[unsafe(no_mangle)]
pub extern "C" fn sie_context_new() -> *mut sie_context {
    without_context(core::ptr::null_mut(), || {
        Box::into_raw(Box::new(sie_context::default()))
    })
}

/// Frees a context and everything it owns (the noise callback's user data is not touched).
/// NULL is a no-op. A call from inside the context's own noise callback is ignored (the
/// context stays alive).
///
/// # Safety
/// `ctx` is NULL or a pointer from `sie_context_new` that has not been freed; no pointer
/// obtained from it (e.g. `sie_context_last_error`) may be used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_free(ctx: *mut sie_context) {
    without_context((), || {
        // SAFETY: NULL or live per the contract.
        let Some(context) = (unsafe { ctx.as_ref() }) else {
            return;
        };
        // A registration further up the stack still uses it.
        if context.state.try_borrow_mut().is_err() {
            return;
        }
        // SAFETY: allocated by `sie_context_new` via Box::into_raw and not yet freed.
        drop(unsafe { Box::from_raw(ctx) });
    })
}

/// Asks the registration running on this context to stop after its current iteration; it
/// then returns `SIE_STATUS_CANCELLED` with the transform reached so far. If none is running,
/// the next registration on this context stops after its first iteration (the request is
/// consumed by the registration it stops). Unlike every other function this one may be called
/// from any thread while another thread uses the context, and from a signal handler (it only
/// sets an atomic flag), e.g. on Ctrl-C. Returns NULL_ARGUMENT for NULL, otherwise OK; it does
/// not touch `sie_context_last_error`.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_cancel(ctx: *const sie_context) -> sie_status {
    without_context(sie_status::Panic, || {
        if ctx.is_null() {
            return sie_status::NullArgument;
        }
        // SAFETY: live per the contract; only the atomic field is referenced, so this is sound
        // while another thread holds the context's RefCells.
        let flag = unsafe { &*core::ptr::addr_of!((*ctx).cancel_requested) };
        flag.store(true, Ordering::Release);
        sie_status::Ok
    })
}

/// The detail message of the last call on this context that returned a status: "" after a
/// success, otherwise what went wrong (names the argument, value or index). Owned by the
/// context; valid until the next call on it. A NULL context gives a static message. Never
/// NULL.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_last_error(ctx: *const sie_context) -> *const c_char {
    without_context(c"".as_ptr(), || {
        // SAFETY: NULL or live per the contract.
        match unsafe { ctx.as_ref() } {
            None => c"ctx is NULL".as_ptr(),
            Some(context) => match context.last_error.try_borrow() {
                Ok(message) => message.as_ptr(),
                Err(_) => c"".as_ptr(),
            },
        }
    })
}

/// C enums are taken as `uint32_t`; this decodes them and rejects unknown values.
pub(crate) trait CEnum: Copy + 'static {
    const ALL: &'static [Self];
    fn code(self) -> u32;

    fn decode(value: u32, argument: &str) -> Result<Self, FfiError> {
        Self::ALL
            .iter()
            .copied()
            .find(|e| e.code() == value)
            .ok_or_else(|| {
                let last = Self::ALL.iter().map(|e| e.code()).max().unwrap_or(0);
                FfiError::invalid(format!(
                    "{argument} = {value} is not a known value (valid: 0..={last})"
                ))
            })
    }
}

macro_rules! c_enum_values {
    ($name:ident: $($variant:ident),+ $(,)?) => {
        impl CEnum for $name {
            const ALL: &'static [Self] = &[$($name::$variant),+];
            fn code(self) -> u32 {
                self as u32
            }
        }
    };
}

c_enum_values!(sie_cost_function: Sie, L2, TruncatedL2, Lp, StudentT, Huber, Cauchy, GemanMcclure, Tukey);
c_enum_values!(sie_metric: PointToPoint, PointToPlane);
c_enum_values!(sie_noise_model: Constant, QuadraticDepth);
c_enum_values!(sie_histogram_mode: Pooled, PerColumn);

#[cfg(test)]
mod tests;
