//! The C ABI (`include/sie.h`, generated from this module by `tests/header.rs`).
//!
//! All `unsafe` code and raw pointers of the crate live here. Every exported function runs its
//! body inside `boundary::boundary` (panics become `SIE_STATUS_PANIC`), reads caller memory
//! into owned values first and writes outputs only after everything succeeded.
//!
//! cbindgen ignores modules, so every exported name is unique and `sie_`-prefixed.
#![allow(unsafe_code)] // the crate root denies it everywhere else
#![allow(non_camel_case_types)]

mod boundary;
mod callback;
#[macro_use] // `CEnum!`, for the enums below
mod c_enum;
mod input;

// cbindgen emits functions in parse order (this file, then these modules as declared), so
// they are kept in the order the header should read: configure, register, query, estimate.
mod settings;

mod register;

mod target;

mod odometry;

mod results;

mod estimate;

use core::ffi::{c_char, c_void};
use std::cell::UnsafeCell;
use std::ffi::{CStr, CString};
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};

use crate::{RegistrationConfig, RegistrationResult};
use boundary::{static_c_str, without_context};
pub(crate) use c_enum::CEnum;
use callback::{NoiseCallback, ProgressCallback};
use macro_rules_attribute::macro_rules_derive;

pub use estimate::*;
pub use odometry::*;
pub use register::*;
pub use results::*;
pub use settings::*;
pub use target::*;

/// Status returned by every fallible function. `SIE_STATUS_OK` is 0, so `if (status)` tests
/// for failure; `sie_context_last_error` then has the details. Functions taking a status
/// (`sie_status_str`) take it as `uint32_t`.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
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
    /// The context is in use by another call: a registration further up the stack (a call
    /// from inside its noise or progress callback) or, against the one-call-at-a-time
    /// contract, a call on another thread. Nothing was changed, not even the context's error
    /// message (`sie_context_last_error` gives a fixed text while the context is in use).
    Busy = 8,
    /// The registration was cancelled (`sie_context_cancel` or a progress callback returning
    /// non-zero). Not a failure: the transform reached so far WAS written to
    /// `out_T_target_source` and the result stored (stop reason CANCELLED).
    Cancelled = 9,
    /// Not enough memory for this input: a buffer sized by a count, or the working set of the
    /// registration (asked for before it starts), could not be allocated; nothing was written
    /// and the process is unharmed. The message says how much was needed.
    OutOfMemory = 10,
    /// An internal error (a Rust panic) was caught; the stored result was discarded. Please
    /// report it with the message from `sie_context_last_error`.
    Panic = 100,
}

impl sie_status {
    /// The short text `sie_status_str` returns for this status (static, NUL-terminated).
    const fn message(self) -> &'static CStr {
        match self {
            Self::Ok => c"ok",
            Self::NullArgument => c"null argument",
            Self::InvalidArgument => c"invalid argument",
            Self::NonFiniteInput => c"non-finite input",
            Self::TooFewPoints => c"too few points",
            Self::CallbackFailed => c"noise callback failed",
            Self::NoResult => c"no result",
            Self::BufferTooSmall => c"buffer too small",
            Self::Busy => c"context busy",
            Self::Cancelled => c"cancelled",
            Self::OutOfMemory => c"out of memory",
            Self::Panic => c"internal panic",
        }
    }
}

/// The robust cost used to weight correspondences (`sie_context_set_cost_function`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
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
#[macro_rules_derive(CEnum!)]
pub enum sie_metric {
    /// r = T*p_source - p_target (3 components).
    PointToPoint = 0,
    /// r = n_target^T (T*p_source - p_target) (1 component; the default).
    PointToPlane = 1,
}

/// Built-in per-point noise model (`sie_context_set_noise_model`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_noise_model {
    /// Same noise everywhere (the default): residuals are not normalised.
    Constant = 0,
    /// Depth cameras: sigma ~ z^2 with z along the optical axis of each cloud's own frame.
    QuadraticDepth = 1,
}

/// Which residuals share an SIE histogram (`sie_context_set_histogram_mode`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_histogram_mode {
    /// One histogram of |r| over all residual components (the default).
    Pooled = 0,
    /// One signed histogram per residual component.
    PerColumn = 1,
}

/// Why a registration stopped (`sie_summary.stop_reason`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
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

/// Where SIE starts (`sie_context_set_starts`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_starts {
    /// Several starts, the most significant result is kept (the default). Correspondences:
    /// the initial guess and the best poses of a threshold-free hypothesis search. Clouds: the
    /// initial guess with the paper's beta0, with a narrow beta0, and after a scale-free (L1)
    /// lead; the search ends after the paper's start when its result is GOOD on its own
    /// evidence and either moved little (10 fitted sigma), corrected the guess locally (within
    /// half the target's spread, every direction fixed by its surfaces; `starts_run` 1) or the
    /// paper's run from it stays there (`starts_run` 2, `agreeing_starts` 2). Applies to the SIE cost with the automatic initial beta; baseline costs and a
    /// fixed initial beta (`sie_context_set_regularizer`) run once from the initial guess.
    Automatic = 0,
    /// One run from the initial guess: the paper's method as published. A run that ends more
    /// than 10 fitted sigma from the guess, and further than a local correction (half the
    /// target's spread, every direction fixed by its surfaces), is run once more from its result
    /// and the more significant of the two kept (a pose the method does not return to is no answer).
    /// When that far result is still not GOOD, a narrow beta (1/256 of the RMS residual) runs
    /// from the guess too: a small overlap near the guess, which the wide first levels left.
    InitialGuess = 1,
    /// Clouds from any pose, no guess needed: FPFH descriptors of both clouds at a scale chosen
    /// from the data (a voxel leaving each a few thousand keypoints, never finer than its point
    /// spacing), mutual matches, the threshold-free hypothesis search on them, then SIE from
    /// the initial guess and from the 4 most significant poses found, the most significant
    /// result kept (starts ending elsewhere lower its margin, so disagreeing candidates are not
    /// GOOD). Costs the descriptors (about 0.1-0.5 s on 2 cores) and up to 5 SIE runs. Clouds
    /// under 50 keypoints with a normal, or whose normals all point one way (a plane), are
    /// refused with SIE_STATUS_TOO_FEW_POINTS and the reason in `sie_context_last_error`.
    /// SIE with the automatic beta0 only (else one run from the guess); correspondences: as
    /// AUTOMATIC.
    Global = 2,
}

/// How far to trust a registration (`sie_summary.verdict`), from the evidence in the other
/// quality fields of `sie_summary`. `converged` only says that the iterations settled; this
/// says whether the data support the pose they settled at.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_verdict {
    /// No result (a summary that was never filled).
    None = 0,
    /// The evidence supports the pose: a significant inlier cluster, a pose the inliers
    /// constrain in every direction, no other start ending elsewhere nearly as significant,
    /// (clouds) inlier residuals no wider than the target points' spacing, and a run that
    /// stopped by itself (never at the iteration cap). Use it.
    Good = 1,
    /// Registered, but some of that evidence is weak (see significance, conditioning,
    /// sigma_to_spacing, margin): check the pose before use, or retry from another guess.
    Doubtful = 2,
    /// No inlier cluster stands out from the background of chance matches at the fitted scale:
    /// the data do not support this pose. Reject it.
    Unsupported = 3,
}

/// Which start the returned transform came from (`sie_summary.start`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_start_kind {
    /// The caller's initial guess (the identity when none was given) with the paper's beta0.
    InitialGuess = 0,
    /// The initial guess with beta0 far below the RMS of the initial residuals (clouds).
    NarrowBeta = 1,
    /// A scale-free (L1) run from the initial guess, then SIE (clouds).
    ScaleFreeLead = 2,
    /// A pose found by the hypothesis search (correspondences).
    Hypothesis = 3,
    /// The initial guess with the warm start's noise model (`sie_context_set_warm_start`).
    WarmStart = 4,
    /// Another start's result turned half a turn about one of its inliers' principal axes (a
    /// near-symmetric scene's rival pose), then SIE (clouds).
    HalfTurn = 5,
    /// Another start's result shifted by one period of structure its inliers repeat (a row of
    /// pillars: a rival pose), then SIE (clouds).
    PeriodShift = 6,
    /// A pose proposed by matching FPFH descriptors of the two clouds (SIE_STARTS_GLOBAL), then
    /// SIE (clouds).
    FeatureMatch = 7,
    /// Another start's result turned a quarter turn about one of its inliers' principal axes
    /// and re-centred on the target (a room's rival pose), then SIE (clouds).
    QuarterTurn = 8,
}

/// Which cloud a noise callback call is about (its `cloud` argument).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_cloud {
    /// The source cloud (the one moved by T_target_source).
    Source = 0,
    /// The target cloud.
    Target = 1,
}

/// Per-point noise callback: fill `out_sigma[i]` with the relative noise sigma (finite, > 0) of
/// point i given in `xyz` (3*n packed doubles, in that cloud's own frame, i.e. the source
/// cloud untransformed). `out_sigma` is pre-filled with 1.0. `cloud` is a `sie_cloud`. The
/// points are those the registration works on: dropped ones left out, and a location the
/// cloud holds several times given once, so `n` can be less than the cloud's count.
///
/// Called once per cloud per registration (never per point), synchronously on the thread that
/// called the registration function. Return 0 on success; any other value aborts the
/// registration with `SIE_STATUS_CALLBACK_FAILED` and the value in the message. It must not
/// unwind or throw, and must not free the context; other calls on the same context from inside
/// it return `SIE_STATUS_BUSY`. The pointers are valid only during the call.
///
/// Never leave it with `longjmp` (or a C++ exception through C frames): that skips the
/// library's cleanup, so the context stays in use for good (every later call on it returns
/// BUSY, `sie_context_free` ignores it and it leaks) along with the registration's memory.
/// Return non-zero instead, and longjmp after the registration has returned.
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
/// on the same context from inside it return `SIE_STATUS_BUSY`. Never leave it with `longjmp`
/// (see `sie_noise_fn`: the context would stay BUSY for good); return non-zero to stop.
///
/// With SIE_STARTS_AUTOMATIC it sees the updates of every start in order (`iteration` numbers
/// them on); the returned transform is the last update of the start that won, which need not
/// be the last one seen.
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
    /// Noise shape p (2 = Gaussian unless estimated).
    pub noise_shape: f64,
    /// sum P(inlier) / source_count at the returned transform (unmatched points count 0).
    pub inlier_fraction: f64,
    /// sqrt(sum P*|r|^2 / sum P), input units (plane distance for point-to-plane).
    pub rmse: f64,
    /// Largest change made to an entry of the initial guess's rotation block to make it an
    /// exact rotation (guesses up to 1e-3 from orthonormal are accepted); 0 without a guess.
    /// Above 1e-6 the guess was visibly rounded (e.g. printed with 5 digits).
    pub init_correction: f64,
    /// Number of source points (length of the per-point result arrays).
    pub source_count: u64,
    /// Number of source points matched to a target point.
    pub correspondence_count: u64,
    /// Number of updates made, by every start (`sie_context_set_starts`).
    pub iterations: u32,
    /// A `sie_stop_reason`.
    pub stop_reason: u32,
    /// Number of SIE histograms (`sie_context_get_histogram` indices; 0 for baseline costs).
    pub histogram_count: u32,
    /// True when stop_reason is SIE_STOP_REASON_CONVERGED.
    pub converged: bool,
    /// How far to trust the result, a `sie_verdict`: GOOD, DOUBTFUL or UNSUPPORTED. The fields
    /// below up to `margin` are its evidence.
    pub verdict: u32,
    /// Which start the transform came from, a `sie_start_kind`.
    pub start: u32,
    /// Significance of the inlier cluster at the returned transform, at the scale of the
    /// fitted sigma: -ln of a bound on the probability that chance matches form a cluster that
    /// large (nats; 0 when nothing stands out from chance, which makes the verdict UNSUPPORTED).
    pub significance: f64,
    /// How well the weighted inliers constrain the pose at the last update, 0..1 (the least
    /// over the most constrained direction); below 0.02 (inliers on one plane or one line, or
    /// only surfaces that run along the motion) the verdict is not GOOD.
    pub conditioning: f64,
    /// Fitted sigma over the typical distance between neighbouring target points (clouds; 0 for
    /// correspondences, which have no spacing). Above 1 the verdict is not GOOD. DBL_MAX when
    /// that spacing is 0 (most target points have an exact duplicate).
    pub sigma_to_spacing: f64,
    /// significance / runner_up_significance: how much more significant the result is than the
    /// best start that ended at another pose; below 2 the verdict is not GOOD. 0 when no start
    /// ended elsewhere (runner_up_significance is then 0): nothing to compare with, so no limit
    /// (the value would be infinite; outputs are always finite).
    pub margin: f64,
    /// The largest significance among starts that ended at another pose (0: none did).
    pub runner_up_significance: f64,
    /// Starts SIE was run from (1 with SIE_STARTS_INITIAL_GUESS, a baseline cost or a fixed
    /// initial beta).
    pub starts_run: u32,
    /// Minimal samples drawn by the hypothesis search of correspondence registration, or of
    /// SIE_STARTS_GLOBAL on descriptor matches (0 when none ran).
    pub hypotheses: u32,
    /// Starts whose result is the returned pose (within 3 standard errors), itself included.
    pub agreeing_starts: u32,
}

/// One fitted SIE histogram model (`sie_context_get_histogram`, `sie_estimate_inliers`).
/// Residual units are normalised (input units with the constant noise model).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sie_model {
    /// Centre of the inlier model (0 for pooled |r| histograms).
    pub mu: f64,
    /// Fitted inlier sigma. Every field is finite: a model too wide for the residuals' unit
    /// (residuals near DBL_MAX) saturates at +-DBL_MAX.
    pub sigma: f64,
    /// Model height at the peak, in counts per bin.
    pub alpha: f64,
    /// Noise shape p of the generalised Gaussian (2 = Gaussian), as `sie_summary.noise_shape`.
    pub noise_shape: f64,
    /// Regulariser beta added to sigma when predicting.
    pub beta: f64,
    /// Penalty k used for the fit.
    pub penalty: f64,
    /// Histogram interval [range_lo, range_hi).
    pub range_lo: f64,
    /// Upper end of the histogram interval (exclusive).
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
    /// Regulariser beta of the first histogram at this iteration (0 for baselines).
    pub beta: f64,
    /// Penalty k of the first histogram at this iteration (0 for baselines).
    pub penalty: f64,
    /// sum P(inlier) / source points, as `sie_summary.inlier_fraction` (unmatched points count
    /// 0), over the source points this iteration matched, with this update's weights.
    pub inlier_fraction: f64,
    /// Weighted RMS residual (input units).
    pub rmse: f64,
    /// Size of this update: translation (input units) and rotation (radians).
    pub translation_change: f64,
    /// Rotation angle of this update (radians).
    pub rotation_change: f64,
    /// Correspondences (matched rows) this iteration used.
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
    /// How much its initial guess was corrected to be exactly rigid (`sie_summary`).
    pub(crate) init_correction: f64,
}

/// What the call that owns a context may touch.
#[derive(Default)]
pub(crate) struct Owned {
    pub(crate) state: ContextState,
    /// The message of the last call that ran (`sie_context_last_error`).
    last_error: CString,
}

impl Owned {
    fn set_last_error(&mut self, message: &str) {
        // An interior NUL would cut the message short in C; show it instead.
        self.last_error = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    }
}

/// A registration context: configuration, noise callback, last result and last error.
/// Create with `sie_context_new`, free with `sie_context_free`.
///
/// A context may be used from any thread, but by one call at a time (this includes the
/// functions taking `const sie_context*`). Distinct contexts are independent; the library has
/// no global state.
///
/// Every call first takes the context (a try-lock, `busy`) and gives it back when it returns; a
/// call that finds it taken returns BUSY without touching anything else. So misuse (a call
/// from inside a callback, or from a second thread) is always refused, never a data race, and
/// the state is only ever reached through the one owning call.
#[derive(Default)]
pub struct sie_context {
    busy: BusyFlag,
    owned: UnsafeCell<Owned>,
    /// Set by `sie_context_cancel` (any thread, or a signal handler); consumed by the
    /// registration it stops. Outside `owned` so that setting it never needs the context.
    pub(crate) cancel_requested: AtomicBool,
}

// SAFETY: `owned` is only reached through a `Taken`, of which at most one exists at a time (the
// try-lock `busy`, which orders successive owners); the other fields are atomic. The callbacks'
// raw user-data pointers are the caller's to share.
unsafe impl Sync for sie_context {}
// SAFETY: as above; nothing in a context is tied to the thread that created it.
unsafe impl Send for sie_context {}

/// The context's try-lock. On Unix a pthread mutex (only ever `trylock`ed, so it cannot block
/// or deadlock, also when a callback calls back in on the same thread): thread checkers such as
/// helgrind understand it, whereas they report every access ordered by a plain atomic flag as a
/// race. Elsewhere an atomic flag (acquire on taking, release on giving back).
#[cfg(unix)]
struct BusyFlag(UnsafeCell<libc::pthread_mutex_t>);

#[cfg(unix)]
impl Default for BusyFlag {
    fn default() -> Self {
        // Static initialisation: plain data until first locked, so it may move until then
        // (`sie_context_new` boxes the context before any call can take it).
        BusyFlag(UnsafeCell::new(libc::PTHREAD_MUTEX_INITIALIZER))
    }
}

#[cfg(unix)]
impl BusyFlag {
    fn try_take(&self) -> bool {
        // SAFETY: an initialised mutex at a fixed address (the context is boxed).
        unsafe { libc::pthread_mutex_trylock(self.0.get()) == 0 }
    }

    fn give_back(&self) {
        // SAFETY: taken by this call (`try_take` returned true).
        unsafe { libc::pthread_mutex_unlock(self.0.get()) };
    }
}

#[cfg(unix)]
impl Drop for BusyFlag {
    fn drop(&mut self) {
        // SAFETY: not locked: `sie_context_free` gives the context back before dropping it.
        unsafe { libc::pthread_mutex_destroy(self.0.get()) };
    }
}

#[cfg(not(unix))]
#[derive(Default)]
struct BusyFlag(AtomicBool);

#[cfg(not(unix))]
impl BusyFlag {
    fn try_take(&self) -> bool {
        self.0
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .is_ok()
    }

    fn give_back(&self) {
        self.0.store(false, Ordering::Release);
    }
}

/// Exclusive use of a context by one call; given back on drop (also while unwinding).
pub(crate) struct Taken<'a> {
    context: &'a sie_context,
}

impl sie_context {
    /// The context for this call, or `None` while another call (further up the stack, or on
    /// another thread) has it.
    pub(crate) fn take(&self) -> Option<Taken<'_>> {
        // Lazily: a `Taken` gives the context back when dropped.
        self.busy.try_take().then(|| Taken { context: self })
    }
}

impl Deref for Taken<'_> {
    type Target = Owned;
    fn deref(&self) -> &Owned {
        // SAFETY: this is the only `Taken` of the context (see `take`).
        unsafe { &*self.context.owned.get() }
    }
}

impl DerefMut for Taken<'_> {
    fn deref_mut(&mut self) -> &mut Owned {
        // SAFETY: this is the only `Taken` of the context (see `take`).
        unsafe { &mut *self.context.owned.get() }
    }
}

impl Drop for Taken<'_> {
    fn drop(&mut self) {
        self.context.busy.give_back();
    }
}

/// `sie_context_last_error` while another call has the context.
const BUSY_MESSAGE: &CStr =
    c"the context is busy: another call is using it (a call from inside its callback, or from another thread)";

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
    const UNKNOWN: &CStr = c"unknown status";
    without_context(UNKNOWN.as_ptr(), || {
        sie_status::from_u32(status)
            .map_or(UNKNOWN, sie_status::message)
            .as_ptr()
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
        // A call further up the stack (or, against the contract, on another thread) still
        // uses it.
        if context.take().is_none() {
            return;
        }
        message_copies::forget(ctx as usize);
        // SAFETY: allocated by `sie_context_new` via Box::into_raw and not yet freed; no call
        // was using it just now, and the contract rules out one starting.
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
/// success, otherwise what went wrong (names the argument, value or index). A call that
/// returned BUSY leaves it unchanged. While another call is using the context (from inside its
/// callbacks, say) it is a static text saying so; a NULL context gives a static message.
/// Never NULL.
///
/// The text is the calling thread's own copy, valid until this thread asks for this context's
/// message again, frees the context, or exits (each thread keeps the copies of its 64 most
/// recently asked contexts). So a message being read can never be replaced by a call on
/// another thread.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_last_error(ctx: *const sie_context) -> *const c_char {
    without_context(c"".as_ptr(), || {
        // SAFETY: NULL or live per the contract.
        match unsafe { ctx.as_ref() } {
            None => c"ctx is NULL".as_ptr(),
            Some(context) => match context.take() {
                Some(taken) => message_copies::store(ctx as usize, &taken.last_error)
                    .unwrap_or(c"(the message is not available while this thread exits)".as_ptr()),
                None => BUSY_MESSAGE.as_ptr(),
            },
        }
    })
}

/// Each thread's copies of the messages it asked for (`sie_context_last_error`), keyed by
/// context address: a per-thread copy cannot be replaced by another thread's call.
mod message_copies {
    use core::ffi::c_char;
    use std::cell::RefCell;
    use std::ffi::{CStr, CString};

    /// Enough for any reasonable number of contexts used on one thread at a time, and a bound
    /// for threads that ask for the messages of contexts freed elsewhere.
    const PER_THREAD: usize = 64;

    thread_local! {
        static COPIES: RefCell<Vec<(usize, CString)>> = const { RefCell::new(Vec::new()) };
    }

    /// Stores this thread's copy of `message` for the context at `address`, replacing its
    /// previous one; `None` while the thread is being torn down.
    pub(super) fn store(address: usize, message: &CStr) -> Option<*const c_char> {
        COPIES
            .try_with(|copies| {
                let mut copies = copies.try_borrow_mut().ok()?;
                copies.retain(|(a, _)| *a != address);
                if copies.len() >= PER_THREAD {
                    copies.remove(0);
                }
                copies.push((address, message.to_owned()));
                copies.last().map(|(_, text)| text.as_ptr())
            })
            .ok()
            .flatten()
    }

    /// Drops this thread's copy for a context being freed.
    pub(super) fn forget(address: usize) {
        let _ = COPIES.try_with(|copies| {
            if let Ok(mut copies) = copies.try_borrow_mut() {
                copies.retain(|(a, _)| *a != address);
            }
        });
    }
}

// The tests call the ABI on buffers they own and size for each call.
#[cfg(test)]
#[allow(clippy::undocumented_unsafe_blocks)]
mod tests;
