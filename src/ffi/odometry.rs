//! Odometry: a sensor's frames registered one after another (`crate::Odometry`), a bad frame
//! set aside with its own status.
#![allow(non_snake_case)]

use macro_rules_attribute::macro_rules_derive;

use super::boundary::{FfiError, boundary, without_context};
use super::input::{Coordinate, check_output, read_points, row_major, write_output};
use super::register::{cancelled_error, run_with_context_hooks};
use super::{sie_context, sie_status};
use crate::{FrameStatus, Odometry};

/// What became of a frame given to `sie_context_odometry_register_frame` (`*out_frame_status`).
/// A frame refused as input is not among them: the call returns its error status instead.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[macro_rules_derive(CEnum!)]
pub enum sie_frame_status {
    /// The first usable frame: its sensor is the world frame (the pose written is the
    /// identity).
    First = 0,
    /// Registered onto the last accepted frame with a GOOD verdict, or bridged over the
    /// NOT_GOOD frame just before it (see NOT_GOOD) GOOD: its pose was written.
    Accepted = 1,
    /// Bit for bit the last accepted frame again (a driver that sent it twice): ignored,
    /// nothing written but this status.
    Repeated = 2,
    /// Registered, but the verdict is not GOOD: ignored (the context holds the result, whose
    /// summary says why); the pose was not written. When it is the frame after the last
    /// accepted one and failed GOOD only for its conditioning, a rival start or its settling,
    /// the next frame that does not register onto the last accepted one registers onto this
    /// one, and is taken (ACCEPTED or LOOSE, its pose through this frame's) when that result
    /// is GOOD or loose and its motion agrees with this frame's (constant velocity); the
    /// context then holds that registration. Before any motion is measured, that bridge goes
    /// first, and a first motion the guess did not give is looked for by the global stage
    /// (once, under the automatic starts): taken when GOOD, else set aside for the next frame
    /// to bridge over when it failed GOOD only for its conditioning or settling.
    NotGood = 3,
    /// Registered GOOD (or LOOSE), but, once a motion has been measured, further from the
    /// constant-velocity guess than the frame's points are from its sensor (median range): no
    /// tracking explains such a jump; ignored, the pose was not written (the context holds the
    /// result).
    Jumped = 4,
    /// Registered DOUBTFUL for its conditioning alone (every other check of GOOD passed, no
    /// start ended elsewhere), a motion already measured (or bridged over a NOT_GOOD frame
    /// whose motion it agrees with), and within tracking's reach: the
    /// data fix some direction of the pose weakly (the summary names it). Accepted as ACCEPTED is, its pose written: the next frames see the same view,
    /// and setting them aside would register each further from its keyframe.
    Loose = 5,
}

/// Frame-to-frame odometry: each frame registers onto the last accepted frame from a
/// constant-velocity guess, and only a GOOD registration (or a LOOSE one: GOOD but for its
/// conditioning) moves the trajectory. Create with
/// `sie_context_odometry_new`, feed frames with `sie_context_odometry_register_frame`, free with
/// `sie_odometry_free`. One call at a time per odometry (it changes with every frame).
pub struct sie_odometry {
    odometry: Odometry,
}

/// Creates an odometry with a copy of the context's settings (later changes to the context do
/// not reach it). Frames from sensors mark missing returns with NaN or 0 0 0: set
/// `skip_non_finite` and `skip_origin` on the context first to drop them. On success
/// `*out_odometry` receives a new odometry; on error it is not written. Errors: NULL_ARGUMENT,
/// INVALID_ARGUMENT (a setting), BUSY.
///
/// # Safety
/// `ctx` is NULL or a live context; `out_odometry` is NULL or writable for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_odometry_new(
    ctx: *mut sie_context,
    out_odometry: *mut *mut sie_odometry,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        check_output(out_odometry, "out_odometry")?;
        let odometry = Odometry::new(call.state.config.clone())?;
        let created = Box::into_raw(Box::new(sie_odometry { odometry }));
        // SAFETY: checked non-NULL and aligned; writable per the contract.
        unsafe { write_output(out_odometry, &[created]) };
        Ok(())
    })
}

/// # Safety
/// The pointers satisfy the contract of the exported function calling this.
unsafe fn register_frame_from<T: Coordinate>(
    ctx: *mut sie_context,
    odometry: *mut sie_odometry,
    xyz: *const T,
    count: usize,
    stride_bytes: usize,
    out_T_world_sensor: *mut f64,
    out_frame_status: *mut u32,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = call.state;
        state.result = None;
        check_output(out_T_world_sensor, "out_T_world_sensor")?;
        check_output(out_frame_status, "out_frame_status")?;
        // SAFETY: NULL or live, and used by this call only, per the contract.
        let odometry = &mut unsafe { odometry.as_mut() }
            .ok_or_else(|| FfiError::null("odometry"))?
            .odometry;
        let non_finite = odometry.config().non_finite;
        let read = if count == 0 && !xyz.is_null() {
            Err(FfiError::new(sie_status::TooFewPoints, "count is 0"))
        } else {
            // SAFETY: readable for its count and stride per the contract.
            unsafe { read_points(xyz, count, stride_bytes, "xyz", non_finite) }
        };
        let points = match read {
            Ok(points) => points,
            Err(error) => {
                // A frame came but is unusable: the sensor moved on meanwhile.
                if matches!(
                    error.status,
                    sie_status::TooFewPoints | sie_status::NonFiniteInput
                ) {
                    odometry.skip_frame();
                }
                return Err(error);
            }
        };
        let (outcome, cancelled_by) = run_with_context_hooks(state, call.cancel_requested, |_, hooks| {
            Ok(odometry.register_frame(&points, hooks))
        })?;
        if let Some(error) = outcome.error {
            return Err(error.into());
        }
        let cancelled = outcome
            .result
            .as_ref()
            .and_then(|result| cancelled_error(result, cancelled_by));
        state.result = outcome.result;
        state.init_correction = 0.0;
        if let Some(by) = cancelled {
            return Err(FfiError::new(
                sie_status::Cancelled,
                format!("{by}; the frame was set aside (its result is stored)"),
            ));
        }
        let status = match outcome.status {
            FrameStatus::First => sie_frame_status::First,
            FrameStatus::Accepted => sie_frame_status::Accepted,
            FrameStatus::Repeated => sie_frame_status::Repeated,
            FrameStatus::NotGood => sie_frame_status::NotGood,
            FrameStatus::Jumped => sie_frame_status::Jumped,
            FrameStatus::Loose => sie_frame_status::Loose,
            FrameStatus::InputRejected => unreachable!("a refused frame carries its error"),
        };
        if let Some(pose) = outcome.pose {
            // SAFETY: checked non-NULL and aligned; writable for 16 doubles per the contract.
            unsafe { write_output(out_T_world_sensor, &row_major(&pose)) };
        }
        // SAFETY: checked non-NULL and aligned; writable per the contract.
        unsafe { write_output(out_frame_status, &[status as u32]) };
        Ok(())
    })
}

/// Registers the next frame: `count` float x, y, z triples at `stride_bytes` (0 = packed) in
/// the sensor's frame. On OK `*out_frame_status` receives a `sie_frame_status` and, for FIRST,
/// ACCEPTED and LOOSE only, `out_T_world_sensor` (16 doubles, row-major) the frame's pose; the
/// context holds the frame's registration (ACCEPTED, LOOSE, NOT_GOOD, JUMPED) for the usual
/// queries. A frame of more than 32 768 valid points is registered on about 16 384, one per
/// voxel of a size chosen from it; its per-point results still have one entry per frame point,
/// each that of the point kept in its voxel.
///
/// A frame that cannot be used returns its error and changes nothing the caller holds; the
/// odometry goes on from the last accepted frame as if it had not come, its guess one frame
/// further: TOO_FEW_POINTS (count 0, or no point left after the context's skips),
/// NON_FINITE_INPUT (a NaN or infinite coordinate the settings do not skip), INVALID_ARGUMENT
/// (a frame that cannot meet the last accepted one: different units), OUT_OF_MEMORY.
/// Caller errors (NULL_ARGUMENT, INVALID_ARGUMENT for a bad stride or alignment, BUSY) change
/// nothing either. CANCELLED: the frame was set aside, its result stored, nothing written.
///
/// # Safety
/// `ctx` is NULL or a live context; `odometry` is NULL or a live odometry no other call is
/// using; `xyz` is NULL or readable for `count` points at its stride; `out_T_world_sensor` is
/// NULL or writable for 16 doubles; `out_frame_status` is NULL or writable for one `uint32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_odometry_register_frame(
    ctx: *mut sie_context,
    odometry: *mut sie_odometry,
    xyz: *const f32,
    count: usize,
    stride_bytes: usize,
    out_T_world_sensor: *mut f64,
    out_frame_status: *mut u32,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_frame_from(
            ctx,
            odometry,
            xyz,
            count,
            stride_bytes,
            out_T_world_sensor,
            out_frame_status,
        )
    }
}

/// `sie_context_odometry_register_frame` with `double` points (strides as in
/// `sie_context_register_d`).
///
/// # Safety
/// As `sie_context_odometry_register_frame`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_odometry_register_frame_d(
    ctx: *mut sie_context,
    odometry: *mut sie_odometry,
    xyz: *const f64,
    count: usize,
    stride_bytes: usize,
    out_T_world_sensor: *mut f64,
    out_frame_status: *mut u32,
) -> sie_status {
    // SAFETY: forwarded contract.
    unsafe {
        register_frame_from(
            ctx,
            odometry,
            xyz,
            count,
            stride_bytes,
            out_T_world_sensor,
            out_frame_status,
        )
    }
}

/// Tells the odometry a frame was lost before it could be given (the driver dropped it): the
/// next frame's guess moves one frame further. NULL is a no-op.
///
/// # Safety
/// `odometry` is NULL or a live odometry no other call is using.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_odometry_skip_frame(odometry: *mut sie_odometry) {
    without_context((), || {
        // SAFETY: NULL or live per the contract.
        if let Some(odometry) = unsafe { odometry.as_mut() } {
            odometry.odometry.skip_frame();
        }
    })
}

/// Writes T_world_sensor of the last accepted frame (the identity before the first) to
/// `out_T_world_sensor` (16 doubles, row-major). NULL_ARGUMENT for a NULL argument,
/// INVALID_ARGUMENT for a misaligned output (nothing written), otherwise OK.
///
/// # Safety
/// `odometry` is NULL or a live odometry no other call is changing; `out_T_world_sensor` is
/// NULL or writable for 16 doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_odometry_pose(
    odometry: *const sie_odometry,
    out_T_world_sensor: *mut f64,
) -> sie_status {
    without_context(sie_status::Panic, || {
        // SAFETY: NULL or live per the contract.
        let Some(odometry) = (unsafe { odometry.as_ref() }) else {
            return sie_status::NullArgument;
        };
        if let Err(error) = check_output(out_T_world_sensor, "out_T_world_sensor") {
            return error.status;
        }
        // SAFETY: checked non-NULL and aligned; writable per the contract.
        unsafe { write_output(out_T_world_sensor, &row_major(&odometry.odometry.pose())) };
        sie_status::Ok
    })
}

/// Frees an odometry. NULL is a no-op.
///
/// # Safety
/// `odometry` is NULL or a pointer from `sie_context_odometry_new` not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_odometry_free(odometry: *mut sie_odometry) {
    without_context((), || {
        if !odometry.is_null() {
            // SAFETY: allocated by sie_context_odometry_new via Box::into_raw, freed once.
            drop(unsafe { Box::from_raw(odometry) });
        }
    })
}
