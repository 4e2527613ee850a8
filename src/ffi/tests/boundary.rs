//! What the boundary around every call guarantees: NULL arguments named, panics caught, and a
//! context in use refused with BUSY (from inside a callback or from another thread).

use core::ffi::c_void;
use core::ptr::{null, null_mut};

use super::*;
use crate::ffi::boundary::{FfiError, boundary};

#[test]
fn null_context_is_rejected_everywhere() {
    let mut out_t = [0.0; 16];
    let points = [0.0f32; 3];
    unsafe {
        assert_eq!(
            sie_context_set_max_iterations(null_mut(), 5),
            sie_status::NullArgument
        );
        assert_eq!(sie_context_set_trace(null_mut(), true), sie_status::NullArgument);
        assert_eq!(
            sie_context_register(
                null_mut(),
                points.as_ptr(),
                1,
                0,
                points.as_ptr(),
                1,
                0,
                null(),
                out_t.as_mut_ptr()
            ),
            sie_status::NullArgument
        );
        let mut summary = sie_summary::default();
        assert_eq!(
            sie_context_get_summary(null(), &mut summary),
            sie_status::NullArgument
        );
        let mut probability = [0.0];
        assert_eq!(
            sie_estimate_inliers(
                null_mut(),
                [0.0].as_ptr(),
                1,
                1,
                null(),
                0.0,
                probability.as_mut_ptr(),
                null_mut(),
                0,
                null_mut()
            ),
            sie_status::NullArgument
        );
        sie_context_free(null_mut());
        let message = CStr::from_ptr(sie_context_last_error(null())).to_str().unwrap();
        assert!(message.contains("NULL"), "{message}");
    }
}

#[test]
fn null_arguments_are_named() {
    let ctx = Context::new();
    let points = [0.0f32; 3];
    let mut out_t = [7.0; 16];
    let status = unsafe {
        sie_context_register(
            ctx.0,
            null(),
            1,
            0,
            points.as_ptr(),
            1,
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::NullArgument);
    assert_eq!(ctx.last_error(), "source_xyz is NULL");
    let status = unsafe {
        sie_context_register(
            ctx.0,
            points.as_ptr(),
            1,
            0,
            points.as_ptr(),
            1,
            0,
            null(),
            null_mut(),
        )
    };
    assert_eq!(status, sie_status::NullArgument);
    assert_eq!(ctx.last_error(), "out_T_target_source is NULL");
    assert_eq!(out_t, [7.0; 16]);
    // A success clears the message.
    assert_eq!(unsafe { sie_context_set_seed(ctx.0, 1) }, sie_status::Ok);
    assert_eq!(ctx.last_error(), "");
}

#[test]
fn panic_becomes_status_with_message_and_drops_the_result() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let status = boundary(Some(ctx.get()), |_| -> Result<(), FfiError> {
        panic!("boom {}", 42)
    });
    assert_eq!(status, sie_status::Panic);
    assert_eq!(ctx.last_error(), "internal panic: boom 42");
    assert!(!ctx.has_result());
    // The context stays usable.
    assert_eq!(unsafe { sie_context_set_seed(ctx.0, 3) }, sie_status::Ok);
    // A panic while a registration uses the state leaves the context free for the next call.
    let status = boundary(Some(ctx.get()), |call| {
        call.state.config.seed = 7;
        panic!("inside")
    });
    assert_eq!(status, sie_status::Panic);
    assert_eq!(unsafe { sie_context_set_seed(ctx.0, 4) }, sie_status::Ok);
    assert_eq!(ctx.config().seed, 4);
}

#[test]
fn calls_while_a_registration_holds_the_context_are_busy() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    // A failed call leaves a message; the BUSY calls below must not replace it.
    assert_eq!(
        unsafe { sie_context_set_threads(ctx.0, 5000) },
        sie_status::InvalidArgument
    );
    let message = ctx.last_error();
    assert!(message.contains("threads"), "{message}");
    let held = ctx.get().take().unwrap();
    let mut summary = sie_summary::default();
    unsafe {
        assert_eq!(sie_context_set_seed(ctx.0, 1), sie_status::Busy);
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Busy);
        // While the context is in use its message is a fixed text, not the owner's string.
        assert!(ctx.last_error().contains("busy"), "{}", ctx.last_error());
        // Ignored rather than freeing memory that is in use.
        sie_context_free(ctx.0);
    }
    drop(held);
    assert_eq!(summary, sie_summary::default());
    assert!(ctx.has_result(), "a BUSY call must not touch the state");
    assert_eq!(
        ctx.last_error(),
        message,
        "a BUSY call must not touch the error message"
    );
    assert_eq!(unsafe { sie_context_set_seed(ctx.0, 1) }, sie_status::Ok);
    assert_eq!(ctx.last_error(), "");
}

/// One context used from two threads at once (against the contract): every call either runs
/// or is refused with BUSY, and the context is consistent afterwards. With the former RefCell
/// flag this was a data race (helgrind: the borrow flag and the error string).
#[test]
fn two_threads_on_one_context_are_refused_not_racy() {
    let ctx = Context::new();
    let context = ctx.get();
    let (mut ran, mut refused) = (0usize, 0usize);
    std::thread::scope(|scope| {
        let other = scope.spawn(|| {
            let (mut ran, mut refused) = (0usize, 0usize);
            for seed in 0..20_000u64 {
                match boundary(Some(context), |call| {
                    call.state.config.seed = seed;
                    Err(FfiError::invalid(format!("other thread {seed}")))
                }) {
                    sie_status::InvalidArgument => ran += 1,
                    sie_status::Busy => refused += 1,
                    status => panic!("{status:?}"),
                }
            }
            (ran, refused)
        });
        for seed in 0..20_000u64 {
            let ptr = core::ptr::from_ref(context).cast_mut();
            match unsafe { sie_context_set_seed(ptr, seed) } {
                sie_status::Ok => ran += 1,
                sie_status::Busy => refused += 1,
                status => panic!("{status:?}"),
            }
        }
        let (other_ran, other_refused) = other.join().unwrap();
        ran += other_ran;
        refused += other_refused;
    });
    assert_eq!(ran + refused, 40_000);
    // A refusal means the other call was running, so something ran.
    assert!(ran > 0);
    // Whoever ran last left a consistent state and message.
    let seed = ctx.config().seed;
    let message = ctx.last_error();
    assert!(
        message.is_empty() || message == format!("other thread {seed}"),
        "seed {seed}, message {message:?}"
    );
}

/// What `recording_callback` saw, and what it should return.
struct CallbackLog {
    ctx: *mut sie_context,
    calls: Vec<(u32, Vec<f64>, Vec<f64>)>,
    inner_status: Option<sie_status>,
    return_code: i32,
}

unsafe extern "C" fn recording_callback(
    user_data: *mut c_void,
    cloud: u32,
    xyz: *const f64,
    n: usize,
    out_sigma: *mut f64,
) -> i32 {
    // SAFETY: the test passes a live CallbackLog; the adapter passes 3n and n doubles.
    unsafe {
        let log = &mut *user_data.cast::<CallbackLog>();
        let points = core::slice::from_raw_parts(xyz, 3 * n).to_vec();
        let prefilled = core::slice::from_raw_parts(out_sigma, n).to_vec();
        log.calls.push((cloud, points, prefilled));
        *out_sigma = 2.0;
        log.inner_status = Some(sie_context_set_seed(log.ctx, 99));
        log.return_code
    }
}

#[test]
fn noise_callback_adapter_passes_packed_points_and_reports_failure() {
    use crate::noise::{CloudRole, NoiseScales};
    let ctx = Context::new();
    let mut log = CallbackLog {
        ctx: ctx.0,
        calls: Vec::new(),
        inner_status: None,
        return_code: 0,
    };
    let status = unsafe {
        sie_context_set_noise_callback(ctx.0, Some(recording_callback), (&raw mut log).cast::<c_void>())
    };
    assert_eq!(status, sie_status::Ok);
    let mut callback = ctx.get().take().unwrap().state.noise_callback.unwrap();

    // As during a registration: the state is held while the callback runs.
    let held = ctx.get().take().unwrap();
    let mut sigmas = [f64::NAN; 2];
    let points = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
    assert_eq!(
        callback.point_sigmas(CloudRole::Target, &points, &mut sigmas),
        Ok(())
    );
    assert_eq!(sigmas, [2.0, 1.0]);
    log.return_code = -3;
    let error = callback
        .point_sigmas(CloudRole::Source, &points, &mut sigmas)
        .unwrap_err();
    drop(held);

    assert!(error.contains("-3") && error.contains("source"), "{error}");
    assert_eq!(log.calls.len(), 2);
    assert_eq!(log.calls[0].0, sie_cloud::Target as u32);
    assert_eq!(log.calls[0].1, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    assert_eq!(log.calls[0].2, vec![1.0, 1.0]);
    assert_eq!(log.calls[1].0, sie_cloud::Source as u32);
    assert_eq!(log.inner_status, Some(sie_status::Busy));
    assert_ne!(ctx.config().seed, 99);

    let status = unsafe { sie_context_set_noise_callback(ctx.0, None, null_mut()) };
    assert_eq!(status, sie_status::Ok);
    assert!(ctx.get().take().unwrap().state.noise_callback.is_none());
}
