//! Configuration setters. Each builds the new configuration, validates all of it and only
//! then replaces the old one, so a rejected value leaves the context unchanged.

use core::ffi::c_void;

use super::boundary::{FfiError, boundary};
use super::callback::{NoiseCallback, ProgressCallback};
use super::input::read_warm_start;
use super::{
    CEnum, sie_context, sie_cost_function, sie_histogram_mode, sie_metric, sie_noise_fn, sie_noise_model,
    sie_progress_fn, sie_starts, sie_status, sie_summary,
};
use crate::{
    CostFunction, HistogramMode, Metric, NoiseModel, NoiseShape, NonFinite, RegistrationConfig, Starts,
};

/// Student-t degrees of freedom when the caller passes 0 (Kerl et al. 2013).
const DEFAULT_STUDENT_T_DOF: f64 = 5.0;

/// # Safety
/// `ctx` is NULL or a live context.
unsafe fn update_config(
    ctx: *mut sie_context,
    change: impl FnOnce(&mut RegistrationConfig) -> Result<(), FfiError>,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let mut config = call.state.config.clone();
        change(&mut config)?;
        config.validate()?;
        call.state.config = config;
        Ok(())
    })
}

/// Selects the cost function (a `sie_cost_function`). `parameter` is the TRUNCATED_L2
/// threshold, the LP exponent p in (0, 2], the STUDENT_T degrees of freedom (0 selects 5), or
/// the HUBER / CAUCHY / GEMAN_MCCLURE / TUKEY scale, in normalised residual units (input units
/// with the constant noise model); it is ignored for SIE and L2. Default: SIE.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_cost_function(
    ctx: *mut sie_context,
    cost: u32,
    parameter: f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.cost = match sie_cost_function::decode(cost, "cost")? {
                sie_cost_function::Sie => CostFunction::Sie,
                sie_cost_function::L2 => CostFunction::L2,
                sie_cost_function::TruncatedL2 => CostFunction::TruncatedL2 { threshold: parameter },
                sie_cost_function::Lp => CostFunction::Lp { p: parameter },
                sie_cost_function::StudentT => CostFunction::StudentT {
                    dof: if parameter == 0.0 {
                        DEFAULT_STUDENT_T_DOF
                    } else {
                        parameter
                    },
                },
                sie_cost_function::Huber => CostFunction::Huber { scale: parameter },
                sie_cost_function::Cauchy => CostFunction::Cauchy { scale: parameter },
                sie_cost_function::GemanMcclure => CostFunction::GemanMcClure { scale: parameter },
                sie_cost_function::Tukey => CostFunction::Tukey { scale: parameter },
            };
            Ok(())
        })
    }
}

/// Selects the residual of cloud registration (a `sie_metric`). Correspondence registration
/// always uses point-to-point. Default: POINT_TO_PLANE.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_metric(ctx: *mut sie_context, metric: u32) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.metric = match sie_metric::decode(metric, "metric")? {
                sie_metric::PointToPoint => Metric::PointToPoint,
                sie_metric::PointToPlane => Metric::PointToPlane,
            };
            Ok(())
        })
    }
}

/// Selects where SIE starts (a `sie_starts`): AUTOMATIC runs SIE from several starts and keeps
/// the most significant result (`sie_summary.start`, `starts_run`, `agreeing_starts` report
/// the search), INITIAL_GUESS runs once from the initial guess (the paper's method), GLOBAL
/// needs no guess (descriptor matches propose the starts; see `sie_starts`).
/// Default: AUTOMATIC.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_starts(ctx: *mut sie_context, starts: u32) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.starts = match sie_starts::decode(starts, "starts")? {
                sie_starts::Automatic => Starts::Automatic,
                sie_starts::InitialGuess => Starts::InitialGuess,
                sie_starts::Global => Starts::Global,
            };
            Ok(())
        })
    }
}

/// Starts the following registrations from the noise model of `previous`, the summary of an
/// earlier SIE registration (`sie_context_get_summary`), or clears it (NULL). For sequences
/// registered from good guesses (odometry with a constant-velocity guess, scan-to-map): one
/// run from the initial guess with beta0 = 2 sigma and no annealing far below sigma, none at all
/// when its first level finds the guess within the model's width (6.6 updates a frame against 19
/// cold in the sequence benchmark's room, the same drift). When that run shows the guess was bad (it did not
/// converge, sigma more than doubled, the inlier fraction halved, or it travelled farther than
/// the model could see) or its verdict is not GOOD, the registration runs as without a warm
/// start, by itself
/// (`sie_summary.start` is SIE_START_KIND_WARM_START when the warm run was kept). A `previous`
/// whose own verdict is DOUBTFUL or UNSUPPORTED clears the setting instead: the frame after it
/// rarely keeps its warm run (the same loose scene or bad guess again), which would be paid for
/// and dropped (SIE_VERDICT_NONE, a summary filled by hand, is taken as given).
/// The values are copied; the setting stays until changed (call it after every frame). Ignored
/// by baseline costs. INVALID_ARGUMENT when `previous` holds no SIE model (histogram_count 0:
/// a baseline's summary), an unknown verdict, or values out of range.
///
/// # Safety
/// `ctx` is NULL or a live context; `previous` is NULL or valid for reading one `sie_summary`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_warm_start(
    ctx: *mut sie_context,
    previous: *const sie_summary,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.warm_start = if previous.is_null() {
                None
            } else {
                // SAFETY: non-NULL, and readable per the contract.
                read_warm_start(previous, "previous")?
            };
            Ok(())
        })
    }
}

/// Caps the number of updates of each start (>= 1; several starts may run: the automatic ones,
/// a single start's rerun from its result, half and quarter turns and period shifts, and
/// `sie_summary.iterations` counts the updates of all of them). Default: 200.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_max_iterations(
    ctx: *mut sie_context,
    max_iterations: u32,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.max_iterations = max_iterations;
            Ok(())
        })
    }
}

/// Converged when an update moves the source cloud's centroid by less than `translation` (input
/// units) and rotates by less than `rotation_radians`; both finite and >= 0. Measured at the
/// centroid so the test does not depend on the frame. Default: 1e-6 and 1e-6.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_convergence(
    ctx: *mut sie_context,
    translation: f64,
    rotation_radians: f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.translation_tolerance = translation;
            config.rotation_tolerance = rotation_radians;
            Ok(())
        })
    }
}

/// Selects the built-in per-point noise model (a `sie_noise_model`); a noise callback, when
/// set, takes precedence. Default: CONSTANT.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_noise_model(ctx: *mut sie_context, model: u32) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.noise = match sie_noise_model::decode(model, "model")? {
                sie_noise_model::Constant => NoiseModel::Constant,
                sie_noise_model::QuadraticDepth => NoiseModel::QuadraticDepth,
            };
            Ok(())
        })
    }
}

/// Sets the per-point noise callback (see `sie_noise_fn`) and the `user_data` passed back to it;
/// the library never dereferences or frees `user_data`. A NULL `noise_fn` removes the callback,
/// and the built-in noise model applies again. Default: none.
///
/// # Safety
/// `ctx` is NULL or a live context. `noise_fn` must be safe to call with `user_data` for as long
/// as it is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_noise_callback(
    ctx: *mut sie_context,
    noise_fn: sie_noise_fn,
    user_data: *mut c_void,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        call.state.noise_callback = noise_fn.map(|function| NoiseCallback { function, user_data });
        Ok(())
    })
}

/// Sets the noise shape p of the inlier model: p > 0 is fixed (in [0.1, 10]; 2 =
/// Gaussian, 1 = Laplacian), p = 0 estimates it from the data. Default: 2.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_noise_shape(ctx: *mut sie_context, p: f64) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.sie.noise_shape = if p == 0.0 {
                NoiseShape::Estimated
            } else {
                NoiseShape::Fixed(p)
            };
            Ok(())
        })
    }
}

/// Selects which residuals share an SIE histogram (a `sie_histogram_mode`). Default: POOLED.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_histogram_mode(ctx: *mut sie_context, mode: u32) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.sie.histogram = match sie_histogram_mode::decode(mode, "mode")? {
                sie_histogram_mode::Pooled => HistogramMode::Pooled,
                sie_histogram_mode::PerColumn => HistogramMode::PerColumn,
            };
            Ok(())
        })
    }
}

/// Sets the SIE regulariser annealing: `initial_beta` is the starting beta in normalised residual
/// units (finite and >= 0; 0 = automatic, the RMS of the initial residuals), `shrink` the factor
/// beta is multiplied by after each convergence, in (0, 1). Default: automatic and 0.5.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_regularizer(
    ctx: *mut sie_context,
    initial_beta: f64,
    shrink: f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.initial_beta = if initial_beta == 0.0 {
                None
            } else {
                Some(initial_beta)
            };
            config.beta_shrink = shrink;
            Ok(())
        })
    }
}

/// Cloud registration uses at most this many randomly chosen source points per iteration
/// (0 = all). Default: 0.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_max_correspondences(
    ctx: *mut sie_context,
    max_correspondences: usize,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.max_correspondences = max_correspondences;
            Ok(())
        })
    }
}

/// Neighbours used to estimate target normals for point-to-plane when none are given
/// (3..=1000). Default: 10.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_normal_neighbours(
    ctx: *mut sie_context,
    neighbours: u32,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.normal_neighbours = usize::try_from(neighbours).unwrap_or(usize::MAX);
            Ok(())
        })
    }
}

/// Worker threads for matching and normals (0 = all cores, 1 = the calling thread only;
/// at most 1024). Default: 0.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_threads(ctx: *mut sie_context, threads: u32) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.threads = usize::try_from(threads).unwrap_or(usize::MAX);
            Ok(())
        })
    }
}

/// Seed of the correspondence sampling; equal seeds give equal results. Default: 0x5EED.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_seed(ctx: *mut sie_context, seed: u64) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.seed = seed;
            Ok(())
        })
    }
}

/// Records one `sie_trace_entry` per iteration for `sie_context_get_trace`. Default: false.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_trace(ctx: *mut sie_context, enabled: bool) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.record_trace = enabled;
            Ok(())
        })
    }
}

/// Drop points (pairs, for correspondences) with a NaN or infinite coordinate instead of
/// failing with `SIE_STATUS_NON_FINITE_INPUT` (depth images and PCL clouds with
/// `is_dense = false` carry them). Dropped source points report inlier probability 0 and target
/// index -1; a non-finite target normal counts as "no normal"; the noise callback sees only the
/// kept points. Default: false.
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_skip_non_finite(ctx: *mut sie_context, enabled: bool) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.non_finite = if enabled {
                NonFinite::Skip
            } else {
                NonFinite::Reject
            };
            Ok(())
        })
    }
}

/// Drop points (pairs, for correspondences) at exactly 0 0 0 the same way as
/// `sie_context_set_skip_non_finite` drops non-finite ones: organised clouds from depth sensors
/// mark invalid pixels so; they are not measurements. Kept, all of them are one location, which
/// counts as one point (as every exact duplicate does), but it still matches the other cloud's
/// (at residual 0 at the identity). Dropped source points report inlier probability 0 and
/// target index -1. Default: false (0 0 0 can be a real point).
///
/// # Safety
/// `ctx` is NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_skip_origin(ctx: *mut sie_context, enabled: bool) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        update_config(ctx, |config| {
            config.skip_origin = enabled;
            Ok(())
        })
    }
}

/// Installs (or with NULL `progress_fn`, removes) the per-iteration progress callback; see
/// `sie_progress_fn`. `user_data` is passed back unchanged and never freed by the library.
///
/// # Safety
/// `ctx` is NULL or a live context; a non-NULL `progress_fn` must stay callable with
/// `user_data` for as long as it is installed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_set_progress_callback(
    ctx: *mut sie_context,
    progress_fn: sie_progress_fn,
    user_data: *mut c_void,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        call.state.progress_callback = progress_fn.map(|function| ProgressCallback { function, user_data });
        Ok(())
    })
}
