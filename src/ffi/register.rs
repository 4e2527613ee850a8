//! Registration entry points: clouds (float or double, optional target normals) and given
//! correspondences. All share the same flow: check pointers and counts, copy the inputs, run
//! the core, and only then write `out_T_target_source` and store the result.
// The C signatures are fixed: frame-annotated names (`T_target_source`) and one argument per
// array property.
#![allow(non_snake_case, clippy::too_many_arguments)]

use nalgebra::Matrix4;

use super::boundary::{FfiError, boundary};
use super::input::{Coordinate, check_output, read_points, read_transform, row_major, write_output};
use super::{ContextState, sie_context, sie_status};
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::geometry::Rigid;
use crate::registration::register_owned_clouds;
use crate::{
    Error, Hooks, NoiseScales, NonFinite, Point, RegistrationConfig, RegistrationResult, StopReason,
    TraceEntry,
};

/// A strided array of three coordinates per point, as passed by C.
#[derive(Clone, Copy)]
struct PointArray<T> {
    xyz: *const T,
    count: usize,
    stride_bytes: usize,
    name: &'static str,
    count_name: &'static str,
}

impl<T: Coordinate> PointArray<T> {
    /// # Safety
    /// `xyz` is NULL or valid for `count` points at `stride_bytes`.
    unsafe fn read(self, non_finite: NonFinite) -> Result<Vec<Point>, FfiError> {
        // A NULL array is reported as such even when its count is 0.
        if self.count == 0 && !self.xyz.is_null() {
            return Err(FfiError::new(
                sie_status::TooFewPoints,
                format!("{} is 0", self.count_name),
            ));
        }
        // SAFETY: forwarded contract.
        unsafe { read_points(self.xyz, self.count, self.stride_bytes, self.name, non_finite) }
    }
}

/// Runs the core with the context's configuration and noise source; on success writes the
/// transform and stores the result (the caller has already dropped the previous one).
///
/// `init` is the initial guess as read (its correction is reported in the summary).
///
/// # Safety
/// `out_t_target_source` passed `check_output` and is valid for 16 writes.
pub(super) unsafe fn run_and_store(
    state: &mut ContextState,
    cancel_requested: &AtomicBool,
    out_t_target_source: *mut f64,
    init: Option<Rigid>,
    run: impl FnOnce(&RegistrationConfig, Hooks<'_>, Option<&Matrix4<f64>>) -> Result<RegistrationResult, Error>,
) -> Result<(), FfiError> {
    let (result, cancelled_by) = run_with_context_hooks(state, cancel_requested, |config, hooks| {
        run(config, hooks, init.as_ref().map(|rigid| &rigid.transform))
    })?;
    // SAFETY: per the contract.
    unsafe { write_output(out_t_target_source, &row_major(&result.transform)) };
    let cancelled = cancelled_error(&result, cancelled_by);
    state.result = Some(result);
    state.init_correction = init.map_or(0.0, |rigid| rigid.correction);
    // Not a failure: the transform reached so far was written and the result stored.
    cancelled.map_or(Ok(()), |by| {
        Err(FfiError::new(
            sie_status::Cancelled,
            format!("{by}; the transform so far was written"),
        ))
    })
}

/// Runs `run` with the context's configuration, its noise callback and an observer that
/// answers `sie_context_cancel` and the progress callback; also returns who asked to cancel.
pub(super) fn run_with_context_hooks<R>(
    state: &mut ContextState,
    cancel_requested: &AtomicBool,
    run: impl FnOnce(&RegistrationConfig, Hooks<'_>) -> Result<R, Error>,
) -> Result<(R, Option<String>), FfiError> {
    // The callbacks are Copy; local copies keep `state.config` borrowable alongside them.
    let mut noise_callback = state.noise_callback;
    let progress_callback = state.progress_callback;
    let mut cancelled_by = None;
    let mut observe = |entry: &TraceEntry| {
        if cancel_requested.swap(false, Ordering::AcqRel) {
            cancelled_by = Some("sie_context_cancel".to_string());
            return ControlFlow::Break(());
        }
        match progress_callback.map(|callback| callback.call(entry)) {
            Some(code) if code != 0 => {
                cancelled_by = Some(format!("the progress callback (it returned {code})"));
                ControlFlow::Break(())
            }
            _ => ControlFlow::Continue(()),
        }
    };
    let hooks = Hooks {
        noise: noise_callback.as_mut().map(|c| c as &mut dyn NoiseScales),
        observer: Some(&mut observe),
    };
    let result = run(&state.config, hooks)?;
    Ok((result, cancelled_by))
}

/// "cancelled by … after N iterations" when `result` stopped because `cancelled_by` asked.
pub(super) fn cancelled_error(result: &RegistrationResult, cancelled_by: Option<String>) -> Option<String> {
    cancelled_by
        .filter(|_| result.stop_reason == StopReason::Cancelled)
        .map(|by| format!("cancelled by {by} after {} iterations", result.iterations))
}

/// # Safety
/// The pointers satisfy the contract of the exported function calling this.
unsafe fn register_clouds_from<T: Coordinate>(
    ctx: *mut sie_context,
    source: PointArray<T>,
    target: PointArray<T>,
    target_normals: Option<PointArray<T>>,
    init_t_target_source: *const f64,
    out_t_target_source: *mut f64,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = call.state;
        state.result = None;
        check_output(out_t_target_source, "out_T_target_source")?;
        // SAFETY (all reads): the arrays and the transform are readable per the contract.
        // SAFETY: readable for its count and stride per the contract.
        let source_points = unsafe { source.read(state.config.non_finite) }?;
        // SAFETY: readable for its count and stride per the contract.
        let target_points = unsafe { target.read(state.config.non_finite) }?;
        let normals = match target_normals {
            Some(array) => {
                // SAFETY: readable for its count and stride per the contract.
                Some(unsafe { array.read(state.config.non_finite) }?)
            }
            None => None,
        };
        // SAFETY: NULL or readable for 16 doubles per the contract.
        let init = unsafe { read_transform(init_t_target_source, "init_T_target_source") }?;
        // SAFETY: `out_t_target_source` was checked above and holds 16 doubles per the contract.
        unsafe {
            run_and_store(
                state,
                call.cancel_requested,
                out_t_target_source,
                init,
                |config, hooks, init| {
                    register_owned_clouds(source_points, target_points, normals, init, config, hooks)
                },
            )
        }
    })
}

/// # Safety
/// The pointers satisfy the contract of the exported function calling this.
unsafe fn register_correspondences_from<T: Coordinate>(
    ctx: *mut sie_context,
    source: PointArray<T>,
    target: PointArray<T>,
    init_t_target_source: *const f64,
    out_t_target_source: *mut f64,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = call.state;
        state.result = None;
        check_output(out_t_target_source, "out_T_target_source")?;
        // SAFETY (all reads): the arrays and the transform are readable per the contract.
        // SAFETY: readable for its count and stride per the contract.
        let source_points = unsafe { source.read(state.config.non_finite) }?;
        // SAFETY: readable for its count and stride per the contract.
        let target_points = unsafe { target.read(state.config.non_finite) }?;
        // SAFETY: NULL or readable for 16 doubles per the contract.
        let init = unsafe { read_transform(init_t_target_source, "init_T_target_source") }?;
        // SAFETY: `out_t_target_source` was checked above and holds 16 doubles per the contract.
        unsafe {
            run_and_store(
                state,
                call.cancel_requested,
                out_t_target_source,
                init,
                |config, hooks, init| {
                    crate::register_correspondences(&source_points, &target_points, init, config, hooks)
                },
            )
        }
    })
}

/// Registers the source cloud onto the target cloud (ICP with nearest-neighbour matching)
/// and returns T_target_source, which maps source points into the target frame:
/// p_target = T*p_source.
///
/// Clouds are arrays of `float` x, y, z triples; point i starts `i * stride_bytes` bytes after
/// the pointer (0 = packed, 12). A stride must be a multiple of 4 and at least 12, and the
/// pointer 4-byte aligned; e.g. `&cloud[0].x` with stride `sizeof(pcl::PointXYZ)` (16).
/// Point-to-plane estimates target normals from `normal_neighbours` neighbours (see
/// `sie_context_register_with_normals` to pass them).
///
/// `init_T_target_source`: initial guess, 16 doubles ROW-major (T[4*row + col]; transpose
/// Eigen's default column-major storage), a rigid transform: last row 0 0 0 1 to 1e-6 and
/// rotation block orthonormal to 1e-3 (max |R^T R - I|) with det +1. Rounding is fine: a matrix
/// inverse's, or a published ground truth printed with 5 digits; the guess is made exactly
/// rigid and `sie_summary.init_correction` says by how much. NULL = identity. `out_T_target_source` (16 doubles,
/// row-major) is written only on success; it may be the same array as the initial guess.
///
/// On success the result is stored in the context for the `sie_context_get_*` functions; on
/// any error the previous result is discarded. Non-convergence is not an error (see
/// `sie_summary.converged`). Errors: NULL_ARGUMENT, INVALID_ARGUMENT (stride, alignment,
/// transform, a count beyond the address space, clouds in different units: one fits between
/// two neighbouring points of the other, as millimetres against metres, or is the same kind of
/// cloud 20 times or more smaller, as centimetres or inches against metres), TOO_FEW_POINTS (a count
/// is 0 or too small),
/// NON_FINITE_INPUT (names the array and point index), CALLBACK_FAILED, BUSY, OUT_OF_MEMORY
/// (the copies of the clouds or the registration's working set, about 450 bytes per source
/// and 160 per target point, cannot be allocated; checked before the registration starts).
///
/// # Safety
/// `ctx` is NULL or a live context; each non-NULL array is readable for its count of points at
/// its stride; `init_T_target_source` is NULL or readable for 16 doubles;
/// `out_T_target_source` is NULL or writable for 16 doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register(
    ctx: *mut sie_context,
    source_xyz: *const f32,
    source_count: usize,
    source_stride_bytes: usize,
    target_xyz: *const f32,
    target_count: usize,
    target_stride_bytes: usize,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_clouds_from(
            ctx,
            source_array(source_xyz, source_count, source_stride_bytes),
            target_array(target_xyz, target_count, target_stride_bytes),
            None,
            init_T_target_source,
            out_T_target_source,
        )
    }
}

/// `sie_context_register` for `double` clouds: stride 0 = packed (24), otherwise a multiple of
/// 8 and at least 24; pointers 8-byte aligned.
///
/// # Safety
/// As `sie_context_register`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_d(
    ctx: *mut sie_context,
    source_xyz: *const f64,
    source_count: usize,
    source_stride_bytes: usize,
    target_xyz: *const f64,
    target_count: usize,
    target_stride_bytes: usize,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_clouds_from(
            ctx,
            source_array(source_xyz, source_count, source_stride_bytes),
            target_array(target_xyz, target_count, target_stride_bytes),
            None,
            init_T_target_source,
            out_T_target_source,
        )
    }
}

/// `sie_context_register` with one unit normal per target point (float nx, ny, nz at
/// `target_normals_stride_bytes`, 0 = packed), used by point-to-plane instead of estimating
/// them. E.g. for a `pcl::PointCloud<pcl::PointNormal>`: `&cloud[0].normal_x` with stride 48.
/// A normal whose length differs from 1 by more than 1e-3 is INVALID_ARGUMENT, except an exact
/// 0 0 0, which marks a point without a normal (never matched); a NaN normal is
/// NON_FINITE_INPUT.
///
/// # Safety
/// As `sie_context_register`; `target_normals` is NULL or readable for `target_count` normals
/// at its stride.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_with_normals(
    ctx: *mut sie_context,
    source_xyz: *const f32,
    source_count: usize,
    source_stride_bytes: usize,
    target_xyz: *const f32,
    target_count: usize,
    target_stride_bytes: usize,
    target_normals: *const f32,
    target_normals_stride_bytes: usize,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    let normals = PointArray {
        xyz: target_normals,
        count: target_count,
        stride_bytes: target_normals_stride_bytes,
        name: "target_normals",
        count_name: "target_count",
    };
    // SAFETY: forwarded contract.
    unsafe {
        register_clouds_from(
            ctx,
            source_array(source_xyz, source_count, source_stride_bytes),
            target_array(target_xyz, target_count, target_stride_bytes),
            Some(normals),
            init_T_target_source,
            out_T_target_source,
        )
    }
}

/// Registers matched pairs: `source_xyz` point i corresponds to `target_xyz` point i (both
/// `count` float points, strides as in `sie_context_register`), always point-to-point. The
/// result's correspondences are the identity (i -> i). Transform arguments, errors and result
/// storage as in `sie_context_register`.
///
/// # Safety
/// As `sie_context_register`, with `count` points in each array.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_correspondences(
    ctx: *mut sie_context,
    source_xyz: *const f32,
    source_stride_bytes: usize,
    target_xyz: *const f32,
    target_stride_bytes: usize,
    count: usize,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_correspondences_from(
            ctx,
            pair_array(source_xyz, count, source_stride_bytes, "source_xyz"),
            pair_array(target_xyz, count, target_stride_bytes, "target_xyz"),
            init_T_target_source,
            out_T_target_source,
        )
    }
}

/// `sie_context_register_correspondences` for `double` points (strides as in
/// `sie_context_register_d`).
///
/// # Safety
/// As `sie_context_register_correspondences`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_correspondences_d(
    ctx: *mut sie_context,
    source_xyz: *const f64,
    source_stride_bytes: usize,
    target_xyz: *const f64,
    target_stride_bytes: usize,
    count: usize,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_correspondences_from(
            ctx,
            pair_array(source_xyz, count, source_stride_bytes, "source_xyz"),
            pair_array(target_xyz, count, target_stride_bytes, "target_xyz"),
            init_T_target_source,
            out_T_target_source,
        )
    }
}

fn source_array<T>(xyz: *const T, count: usize, stride_bytes: usize) -> PointArray<T> {
    PointArray {
        xyz,
        count,
        stride_bytes,
        name: "source_xyz",
        count_name: "source_count",
    }
}

fn target_array<T>(xyz: *const T, count: usize, stride_bytes: usize) -> PointArray<T> {
    PointArray {
        xyz,
        count,
        stride_bytes,
        name: "target_xyz",
        count_name: "target_count",
    }
}

fn pair_array<T>(xyz: *const T, count: usize, stride_bytes: usize, name: &'static str) -> PointArray<T> {
    PointArray {
        xyz,
        count,
        stride_bytes,
        name,
        count_name: "count",
    }
}
