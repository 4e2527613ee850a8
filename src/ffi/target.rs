//! Prepared targets: a target cloud's kd-tree and normals built once and shared by many
//! registrations, on many contexts and threads.
#![allow(non_snake_case, clippy::too_many_arguments)]

use super::boundary::{FfiError, boundary, without_context};
use super::input::{Coordinate, check_output, read_points, read_transform, write_output};
use super::register::run_and_store;
use super::{sie_context, sie_status};
use crate::registration::register_owned_to;
use crate::{PrepareOptions, PreparedTarget};

/// A prepared target cloud: its points sorted for matching, their kd-tree, and their normals
/// (given, or estimated by the registrations that reach them and kept for later ones).
/// Create with `sie_context_prepare_target`, register onto it with `sie_context_register_to`,
/// free with `sie_target_free`.
///
/// Immutable once created: any number of contexts on any threads may register onto one target
/// at the same time (`const sie_target*`), and results are the same bit for bit as
/// `sie_context_register` on the same clouds, whatever else runs on the target. It holds a copy
/// of the points, so the caller's arrays may be freed after creation. Free it only after every
/// registration using it has returned.
pub struct sie_target {
    prepared: PreparedTarget,
}

/// # Safety
/// The pointers satisfy the contract of the exported function calling this.
unsafe fn prepare_target_from<T: Coordinate>(
    ctx: *mut sie_context,
    xyz: *const T,
    count: usize,
    stride_bytes: usize,
    normals: *const T,
    normals_stride_bytes: usize,
    out_target: *mut *mut sie_target,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = call.state;
        check_output(out_target, "out_target")?;
        let non_finite = state.config.non_finite;
        if count == 0 && !xyz.is_null() {
            return Err(FfiError::new(sie_status::TooFewPoints, "count is 0"));
        }
        // SAFETY (both reads): readable per the contract.
        // SAFETY: readable for its count and stride per the contract.
        let points = unsafe { read_points(xyz, count, stride_bytes, "xyz", non_finite) }?;
        let normals = if normals.is_null() {
            None
        } else {
            // SAFETY: readable for its count and stride per the contract.
            Some(unsafe { read_points(normals, count, normals_stride_bytes, "normals", non_finite) }?)
        };
        let options = PrepareOptions::from_config(&state.config);
        let prepared = PreparedTarget::new(&points, normals.as_deref(), &options)?;
        let target = Box::into_raw(Box::new(sie_target { prepared }));
        // SAFETY: checked non-NULL and aligned; writable per the contract.
        unsafe { write_output(out_target, &[target]) };
        Ok(())
    })
}

/// Prepares a target cloud for `sie_context_register_to`: sorts it, builds its kd-tree, and
/// keeps `normals` if given. `xyz`: `count` float x, y, z triples at `stride_bytes` (0 =
/// packed), as the target of `sie_context_register`. `normals`: NULL (estimated from the
/// context's `normal_neighbours` when point-to-plane first needs them) or `count` unit normals
/// at `normals_stride_bytes`, with 0 0 0 for a point without one (as
/// `sie_context_register_with_normals`).
///
/// The context lends its settings (`normal_neighbours`, `skip_non_finite`, `skip_origin`; a later
/// registration with another `normal_neighbours` is INVALID_ARGUMENT) and its last error; the
/// target does not refer to it afterwards. On success `*out_target` receives a new target (free
/// it with `sie_target_free`); on error it is not written. Errors: NULL_ARGUMENT,
/// INVALID_ARGUMENT (stride, alignment, normal length), TOO_FEW_POINTS, NON_FINITE_INPUT,
/// BUSY, OUT_OF_MEMORY (the copy of the points and the target's working set, about 120 bytes
/// a point and 60 more with normals, cannot be allocated; checked before the target is built).
///
/// # Safety
/// `ctx` is NULL or a live context; `xyz` is NULL or readable for `count` points at its
/// stride; `normals` likewise; `out_target` is NULL or writable for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_prepare_target(
    ctx: *mut sie_context,
    xyz: *const f32,
    count: usize,
    stride_bytes: usize,
    normals: *const f32,
    normals_stride_bytes: usize,
    out_target: *mut *mut sie_target,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        prepare_target_from(
            ctx,
            xyz,
            count,
            stride_bytes,
            normals,
            normals_stride_bytes,
            out_target,
        )
    }
}

/// `sie_context_prepare_target` for `double` points and normals (strides as in
/// `sie_context_register_d`).
///
/// # Safety
/// As `sie_context_prepare_target`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_prepare_target_d(
    ctx: *mut sie_context,
    xyz: *const f64,
    count: usize,
    stride_bytes: usize,
    normals: *const f64,
    normals_stride_bytes: usize,
    out_target: *mut *mut sie_target,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        prepare_target_from(
            ctx,
            xyz,
            count,
            stride_bytes,
            normals,
            normals_stride_bytes,
            out_target,
        )
    }
}

/// Estimates every target normal not estimated yet (point-to-plane without given normals) on
/// `threads` threads (0 = one per core), so that no later registration pays for them: e.g.
/// for a map prepared in the background. Without it, registrations estimate the normals they
/// reach (less work when they reach only part of the target); results are the same either way.
/// May run while other threads register onto the same target. Returns NULL_ARGUMENT for NULL,
/// INVALID_ARGUMENT for more than 1024 threads, OUT_OF_MEMORY when the normals (about 36 bytes
/// a point) cannot be allocated (checked before any is estimated; the target stays usable),
/// otherwise OK.
///
/// # Safety
/// `target` is NULL or a live target.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_target_estimate_normals(target: *const sie_target, threads: u32) -> sie_status {
    without_context(sie_status::Panic, || {
        // SAFETY: NULL or live per the contract.
        let Some(target) = (unsafe { target.as_ref() }) else {
            return sie_status::NullArgument;
        };
        if threads > 1024 {
            return sie_status::InvalidArgument;
        }
        match target.prepared.estimate_all_normals(threads as usize) {
            Ok(_) => sie_status::Ok,
            Err(error) => FfiError::from(error).status,
        }
    })
}

/// Number of points the target was created from (skipped non-finite ones included); 0 for
/// NULL.
///
/// # Safety
/// `target` is NULL or a live target.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_target_point_count(target: *const sie_target) -> usize {
    // SAFETY: NULL or live per the contract.
    without_context(0, || unsafe { target.as_ref() }.map_or(0, |t| t.prepared.len()))
}

/// Frees a target. NULL is a no-op. No registration may be using it.
///
/// # Safety
/// `target` is NULL or a pointer from `sie_context_prepare_target[_d]` not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_target_free(target: *mut sie_target) {
    without_context((), || {
        if !target.is_null() {
            // SAFETY: allocated by prepare_target_from via Box::into_raw, freed once.
            drop(unsafe { Box::from_raw(target) });
        }
    })
}

/// # Safety
/// The pointers satisfy the contract of the exported function calling this.
unsafe fn register_to_from<T: Coordinate>(
    ctx: *mut sie_context,
    source_xyz: *const T,
    source_count: usize,
    source_stride_bytes: usize,
    target: *const sie_target,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = call.state;
        state.result = None;
        check_output(out_T_target_source, "out_T_target_source")?;
        // SAFETY: NULL or live per the contract.
        let target = unsafe { target.as_ref() }.ok_or_else(|| FfiError::null("target"))?;
        if source_count == 0 && !source_xyz.is_null() {
            return Err(FfiError::new(sie_status::TooFewPoints, "source_count is 0"));
        }
        // SAFETY (both reads): readable per the contract.
        // SAFETY: readable for its count and stride per the contract.
        let source = unsafe {
            read_points(
                source_xyz,
                source_count,
                source_stride_bytes,
                "source_xyz",
                state.config.non_finite,
            )
        }?;
        // SAFETY: NULL or readable for 16 doubles per the contract.
        let init = unsafe { read_transform(init_T_target_source, "init_T_target_source") }?;
        // SAFETY: `out_T_target_source` was checked above and holds 16 doubles per the contract.
        unsafe {
            run_and_store(
                state,
                call.cancel_requested,
                out_T_target_source,
                init,
                |config, hooks, init| register_owned_to(source, &target.prepared, init, config, hooks),
            )
        }
    })
}

/// `sie_context_register` onto a prepared target: the source cloud (float, strides as there)
/// is registered onto `target` without rebuilding its kd-tree or re-estimating the normals
/// earlier registrations estimated. Transform arguments, errors (NULL_ARGUMENT for a NULL
/// target) and result storage as in `sie_context_register`; correspondences name the points
/// the target was created from. The same result as `sie_context_register` with the target's
/// arrays, bit for bit. Other contexts may register onto the same target at the same time.
///
/// # Safety
/// As `sie_context_register`; `target` is NULL or a live target.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_to(
    ctx: *mut sie_context,
    source_xyz: *const f32,
    source_count: usize,
    source_stride_bytes: usize,
    target: *const sie_target,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_to_from(
            ctx,
            source_xyz,
            source_count,
            source_stride_bytes,
            target,
            init_T_target_source,
            out_T_target_source,
        )
    }
}

/// `sie_context_register_to` with a `double` source cloud (strides as in
/// `sie_context_register_d`).
///
/// # Safety
/// As `sie_context_register_to`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_register_to_d(
    ctx: *mut sie_context,
    source_xyz: *const f64,
    source_count: usize,
    source_stride_bytes: usize,
    target: *const sie_target,
    init_T_target_source: *const f64,
    out_T_target_source: *mut f64,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_to_from(
            ctx,
            source_xyz,
            source_count,
            source_stride_bytes,
            target,
            init_T_target_source,
            out_T_target_source,
        )
    }
}
