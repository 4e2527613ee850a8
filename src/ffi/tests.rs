//! Boundary, NULL handling, input reading and result getters of the C ABI, exercised through
//! the exported functions. Results are injected into the context so these tests do not depend
//! on the registration driver; tests/c_api.rs covers full registrations from C.

use core::ffi::{CStr, c_void};
use core::ptr::{null, null_mut};

use nalgebra::Matrix4;

use super::boundary::{FfiError, boundary};
use super::input::{read_points, read_transform, row_major, write_buffer};
use super::*;
use crate::cost::CostFunction;
use crate::geometry::NonFinite;
use crate::registration::{
    Metric, Quality, RegistrationResult, SearchReport, StartKind, Starts, StopReason, TraceEntry, Verdict,
};
use crate::sie::shape::GeneralisedGaussian;
use crate::sie::{HistogramMode, HistogramModel, NoiseShape};

/// Owns a context for one test and frees it at the end.
struct Context(*mut sie_context);

impl Context {
    fn new() -> Self {
        let ctx = sie_context_new();
        assert!(!ctx.is_null());
        Context(ctx)
    }

    fn get(&self) -> &sie_context {
        // SAFETY: live until drop.
        unsafe { &*self.0 }
    }

    fn last_error(&self) -> String {
        // SAFETY: live context; the message is NUL-terminated.
        unsafe { CStr::from_ptr(sie_context_last_error(self.0)) }
            .to_str()
            .unwrap()
            .to_owned()
    }

    fn config(&self) -> RegistrationConfig {
        self.get().take().expect("not busy").state.config.clone()
    }

    fn inject_result(&self, result: RegistrationResult) {
        self.get().take().expect("not busy").state.result = Some(result);
    }

    fn has_result(&self) -> bool {
        self.get().take().expect("not busy").state.result.is_some()
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: created by sie_context_new, freed once.
        unsafe { sie_context_free(self.0) }
    }
}

fn histogram() -> HistogramModel {
    HistogramModel {
        inlier: GeneralisedGaussian {
            alpha: 10.0,
            mu: 0.0,
            sigma: 0.5,
            p: 2.0,
        },
        beta: 0.25,
        penalty: 3.0,
        lo: 0.0,
        hi: 2.0,
        counts: vec![9.0, 7.0, 2.0, 1.0],
        smoothed: vec![8.5, 6.5, 2.5, 1.0],
        probability: vec![0.99, 0.9, 0.4, 0.1],
        mean_inlier_probability: 0.7,
        samples_in_range: 19,
        samples_total: 25,
        peak_found: true,
    }
}

fn sample_result() -> RegistrationResult {
    let mut transform = Matrix4::identity();
    transform[(0, 3)] = 1.5;
    transform[(2, 3)] = -0.5;
    RegistrationResult {
        transform,
        stop_reason: StopReason::IterationLimit,
        converged: false,
        iterations: 7,
        sigma: vec![0.5],
        beta: vec![0.25],
        penalty: 3.0,
        noise_shape: 2.0,
        inlier_fraction: 0.6,
        rmse: 0.02,
        probabilities: vec![0.9, 0.0, 0.8],
        correspondences: vec![4, -1, 2],
        histograms: vec![histogram()],
        times: Default::default(),
        search: SearchReport {
            start: StartKind::ScaleFreeLead,
            hypotheses: 0,
            starts_run: 3,
            significance: 41.5,
            agreeing_starts: 2,
            runner_up_significance: 12.0,
        },
        quality: Quality {
            verdict: Verdict::Doubtful,
            significance: 41.5,
            conditioning: 0.25,
            sigma_to_spacing: 0.75,
            margin: 41.5 / 12.0,
        },
        trace: vec![TraceEntry {
            iteration: 1,
            annealing: true,
            sigma: 0.5,
            beta: 0.25,
            penalty: 10.0,
            inlier_fraction: 0.6,
            rmse: 0.03,
            translation_change: 0.1,
            rotation_change: 0.01,
            correspondences: 3,
            transform,
        }],
    }
}

#[test]
fn status_strings_and_version() {
    let text = |status| {
        unsafe { CStr::from_ptr(sie_status_str(status)) }
            .to_str()
            .unwrap()
    };
    assert_eq!(text(sie_status::Ok as u32), "ok");
    assert_eq!(text(sie_status::Busy as u32), "context busy");
    assert_eq!(text(sie_status::Panic as u32), "internal panic");
    assert_eq!(text(sie_status::Cancelled as u32), "cancelled");
    assert_eq!(text(sie_status::OutOfMemory as u32), "out of memory");
    assert_eq!(text(11), "unknown status");
    assert_eq!(text(u32::MAX), "unknown status");
    let version = unsafe { CStr::from_ptr(sie_version_string()) }.to_str().unwrap();
    assert_eq!(version, env!("CARGO_PKG_VERSION"));
    let parts: Vec<u32> = version.split('.').map(|p| p.parse().unwrap()).collect();
    assert_eq!(
        sie_version_number(),
        (parts[0] << 16) | (parts[1] << 8) | parts[2]
    );
}

/// The text table is built from the enum: every status maps back from its number and has a
/// text of its own.
#[test]
fn every_status_has_its_own_text() {
    let mut texts = Vec::new();
    for &status in sie_status::ALL {
        assert_eq!(sie_status::from_u32(status as u32), Some(status));
        let text = unsafe { CStr::from_ptr(sie_status_str(status as u32)) };
        assert_eq!(text, status.message());
        assert!(!texts.contains(&text), "{text:?} twice");
        texts.push(text);
    }
    assert_eq!(sie_status::from_u32(11), None);
}

/// The value tables come from the declarations (`CEnum!`); left to keep by hand are the derive
/// on each C enum and its name in cbindgen.toml's export list (an enum missing there is missing
/// from the header, and the header test cannot tell).
#[test]
fn every_c_enum_derives_its_tables_and_is_in_the_header() {
    let source = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/src/ffi/mod.rs"));
    let header = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/include/sie.h"));
    let lines: Vec<&str> = source.lines().collect();
    let mut enums = Vec::new();
    for (index, line) in lines.iter().enumerate() {
        let Some(name) = line
            .strip_prefix("pub enum ")
            .and_then(|rest| rest.strip_suffix(" {"))
        else {
            continue;
        };
        let attributes: Vec<&str> = lines[..index]
            .iter()
            .rev()
            .take_while(|line| line.starts_with("#["))
            .copied()
            .collect();
        assert!(attributes.contains(&"#[repr(u32)]"), "{name} is not #[repr(u32)]");
        assert!(
            attributes.contains(&"#[macro_rules_derive(CEnum!)]"),
            "{name} does not derive its tables: add #[macro_rules_derive(CEnum!)]"
        );
        assert!(
            header.contains(&format!("\nenum {name}\n")),
            "{name} is not in include/sie.h: add it to [export] include in cbindgen.toml"
        );
        enums.push(name);
    }
    assert_eq!(enums.len(), 10, "{enums:?}");
}

/// An unknown value is rejected with "valid: 0..=last", which holds while the values an
/// argument can take are numbered from 0 without gaps.
#[test]
fn enum_arguments_are_numbered_from_zero() {
    fn check<E: CEnum + core::fmt::Debug + PartialEq>() {
        let codes: Vec<u32> = E::ALL.iter().map(|variant| variant.code()).collect();
        assert_eq!(codes, (0..codes.len() as u32).collect::<Vec<_>>(), "{:?}", E::ALL);
        for &variant in E::ALL {
            assert_eq!(E::decode(variant.code(), "x"), Ok(variant));
        }
        let last = codes.len() as u32 - 1;
        let error = E::decode(last + 1, "x").unwrap_err();
        assert_eq!(
            error.message,
            format!("x = {} is not a known value (valid: 0..={last})", last + 1)
        );
    }
    check::<sie_cost_function>();
    check::<sie_metric>();
    check::<sie_noise_model>();
    check::<sie_histogram_mode>();
    check::<sie_starts>();
}

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
fn setters_store_valid_values() {
    let ctx = Context::new();
    unsafe {
        assert_eq!(
            sie_context_set_cost_function(ctx.0, sie_cost_function::Huber as u32, 0.3),
            sie_status::Ok
        );
        assert_eq!(ctx.config().cost, CostFunction::Huber { scale: 0.3 });
        assert_eq!(
            sie_context_set_cost_function(ctx.0, sie_cost_function::StudentT as u32, 0.0),
            sie_status::Ok
        );
        assert_eq!(ctx.config().cost, CostFunction::StudentT { dof: 5.0 });
        assert_eq!(
            sie_context_set_cost_function(ctx.0, sie_cost_function::L2 as u32, f64::NAN),
            sie_status::Ok,
            "the parameter is ignored for L2"
        );
        assert_eq!(ctx.config().cost, CostFunction::L2);
        assert_eq!(sie_context_set_metric(ctx.0, 0), sie_status::Ok);
        assert_eq!(ctx.config().metric, Metric::PointToPoint);
        assert_eq!(sie_context_set_noise_shape(ctx.0, 0.0), sie_status::Ok);
        assert_eq!(ctx.config().sie.shape_exponent, NoiseShape::Estimated);
        assert_eq!(sie_context_set_noise_shape(ctx.0, 1.0), sie_status::Ok);
        assert_eq!(ctx.config().sie.shape_exponent, NoiseShape::Fixed(1.0));
        assert_eq!(sie_context_set_histogram_mode(ctx.0, 1), sie_status::Ok);
        assert_eq!(ctx.config().sie.histogram, HistogramMode::PerColumn);
        assert_eq!(sie_context_set_regularizer(ctx.0, 0.0, 0.25), sie_status::Ok);
        assert_eq!(
            (ctx.config().initial_beta, ctx.config().beta_shrink),
            (None, 0.25)
        );
        assert_eq!(sie_context_set_regularizer(ctx.0, 2.0, 0.5), sie_status::Ok);
        assert_eq!(ctx.config().initial_beta, Some(2.0));
        assert_eq!(sie_context_set_noise_model(ctx.0, 1), sie_status::Ok);
        assert_eq!(ctx.config().noise, crate::noise::NoiseModel::QuadraticDepth);
        assert_eq!(sie_context_set_convergence(ctx.0, 1e-4, 1e-5), sie_status::Ok);
        assert_eq!(
            (
                ctx.config().translation_tolerance,
                ctx.config().rotation_tolerance
            ),
            (1e-4, 1e-5)
        );
        assert_eq!(sie_context_set_max_correspondences(ctx.0, 500), sie_status::Ok);
        assert_eq!(sie_context_set_normal_neighbours(ctx.0, 20), sie_status::Ok);
        assert_eq!(sie_context_set_threads(ctx.0, 1), sie_status::Ok);
        assert_eq!(sie_context_set_seed(ctx.0, 42), sie_status::Ok);
        assert_eq!(sie_context_set_trace(ctx.0, true), sie_status::Ok);
        assert_eq!(sie_context_set_max_iterations(ctx.0, 9), sie_status::Ok);
        assert_eq!(
            sie_context_set_starts(ctx.0, sie_starts::InitialGuess as u32),
            sie_status::Ok
        );
        assert_eq!(ctx.config().starts, Starts::InitialGuess);
        assert_eq!(sie_context_set_starts(ctx.0, 0), sie_status::Ok);
        assert_eq!(ctx.config().starts, Starts::Automatic);
        assert_eq!(sie_context_set_starts(ctx.0, 1), sie_status::Ok);
    }
    let config = ctx.config();
    assert_eq!(
        (
            config.max_correspondences,
            config.normal_neighbours,
            config.threads,
            config.seed,
            config.record_trace,
            config.max_iterations,
            config.starts
        ),
        (500, 20, 1, 42, true, 9, Starts::InitialGuess)
    );
}

#[test]
fn rejected_setters_keep_the_old_config() {
    let ctx = Context::new();
    let before = ctx.config();
    // The status is evaluated before the closure runs, so last_error belongs to that call.
    let rejected = |status: sie_status, fragment: &str| {
        assert_eq!(status, sie_status::InvalidArgument, "{fragment}");
        let message = ctx.last_error();
        assert!(
            message.contains(fragment),
            "{message:?} should contain {fragment:?}"
        );
    };
    unsafe {
        rejected(sie_context_set_cost_function(ctx.0, 9, 1.0), "cost = 9");
        rejected(sie_context_set_cost_function(ctx.0, 42, 1.0), "cost = 42");
        rejected(sie_context_set_cost_function(ctx.0, 5, -1.0), "-1");
        rejected(sie_context_set_cost_function(ctx.0, 3, 3.0), "Lp { p: 3.0 }");
        rejected(sie_context_set_metric(ctx.0, 2), "metric = 2");
        rejected(
            sie_context_set_starts(ctx.0, 2),
            "starts = 2 is not a known value (valid: 0..=1)",
        );
        rejected(sie_context_set_starts(ctx.0, u32::MAX), "starts = 4294967295");
        rejected(sie_context_set_max_iterations(ctx.0, 0), "max_iterations");
        rejected(
            sie_context_set_convergence(ctx.0, -1.0, 0.0),
            "translation_tolerance",
        );
        rejected(
            sie_context_set_convergence(ctx.0, 0.0, f64::INFINITY),
            "rotation_tolerance",
        );
        rejected(sie_context_set_noise_model(ctx.0, 7), "model = 7");
        rejected(sie_context_set_noise_shape(ctx.0, -2.0), "-2");
        rejected(sie_context_set_noise_shape(ctx.0, f64::NAN), "NaN");
        rejected(sie_context_set_histogram_mode(ctx.0, 2), "mode = 2");
        rejected(sie_context_set_regularizer(ctx.0, -1.0, 0.5), "initial_beta");
        rejected(sie_context_set_regularizer(ctx.0, 0.0, 1.0), "beta_shrink");
        rejected(sie_context_set_normal_neighbours(ctx.0, 2), "normal_neighbours");
        rejected(sie_context_set_threads(ctx.0, 5000), "5000");
    }
    assert_eq!(ctx.config(), before);
}

#[test]
fn documented_defaults_match_the_core() {
    // The setter docs in include/sie.h state these defaults.
    let config = RegistrationConfig::default();
    assert_eq!(config.cost, CostFunction::Sie);
    assert_eq!(config.metric, Metric::PointToPlane);
    assert_eq!(config.max_iterations, 200);
    assert_eq!(
        (config.translation_tolerance, config.rotation_tolerance),
        (1e-6, 1e-6)
    );
    assert_eq!(config.noise, crate::noise::NoiseModel::Constant);
    assert_eq!(config.sie.shape_exponent, NoiseShape::Fixed(2.0));
    assert_eq!(config.sie.histogram, HistogramMode::Pooled);
    assert_eq!((config.initial_beta, config.beta_shrink), (None, 0.5));
    assert_eq!(config.max_correspondences, 0);
    assert_eq!(config.normal_neighbours, 10);
    assert_eq!(config.threads, 0);
    assert_eq!(config.seed, 0x5EED);
    assert!(!config.record_trace);
    assert_eq!(config.starts, Starts::Automatic);
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

/// A float count whose extent at stride 12 fits the address space, but whose f64 copy (24
/// bytes a point) does not: it passed the size check and panicked ("capacity overflow").
#[test]
fn counts_whose_copy_cannot_exist_are_invalid_arguments() {
    let ctx = Context::new();
    let floats = [0.5f32; 12];
    let mut out = [-7.0f64; 16];
    for count in [0x0aaa_aaaa_aaaa_aaa9usize, (isize::MAX as usize) / 12] {
        let status = unsafe {
            sie_context_register(
                ctx.0,
                floats.as_ptr(),
                count,
                12,
                floats.as_ptr(),
                4,
                0,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        let message = ctx.last_error();
        assert!(
            message.contains("source_xyz") && message.contains("address space"),
            "{message}"
        );
        let status = unsafe {
            sie_context_register_correspondences(
                ctx.0,
                floats.as_ptr(),
                0,
                floats.as_ptr(),
                0,
                count,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        let status = unsafe {
            sie_context_register_with_normals(
                ctx.0,
                floats.as_ptr(),
                4,
                0,
                floats.as_ptr(),
                count,
                12,
                floats.as_ptr(),
                12,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        assert!(ctx.last_error().contains("target_xyz"), "{}", ctx.last_error());
    }
    assert!(out.iter().all(|&v| v == -7.0), "outputs must stay untouched");
}

#[repr(C)]
struct PaddedPoint {
    x: f32,
    y: f32,
    z: f32,
    pad: f32,
}

#[test]
fn points_are_read_with_byte_strides() {
    let cloud: Vec<PaddedPoint> = (0..4)
        .map(|i| PaddedPoint {
            x: i as f32,
            y: 10.0 + i as f32,
            z: 20.0 + i as f32,
            pad: f32::NAN,
        })
        .collect();
    let points =
        unsafe { read_points(&raw const cloud[0].x, 4, 16, "source_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points[3], [3.0, 13.0, 23.0]);

    let packed = [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0];
    let points = unsafe { read_points(packed.as_ptr(), 2, 0, "target_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    // Stride 32 over doubles: every other triple... of a 4-double record.
    let records = [1.0f64, 2.0, 3.0, -1.0, 4.0, 5.0, 6.0, -1.0];
    let points = unsafe { read_points(records.as_ptr(), 2, 32, "target_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);

    for (stride, scalar) in [(10, "float"), (14, "float"), (8, "float")] {
        let error = unsafe { read_points(&raw const cloud[0].x, 4, stride, "source_xyz", NonFinite::Reject) }
            .unwrap_err();
        assert_eq!(error.status, sie_status::InvalidArgument, "{stride}");
        assert!(error.message.contains(scalar) && error.message.contains(&stride.to_string()));
    }
    let error = unsafe { read_points(packed.as_ptr(), 1, 12, "target_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    let misaligned = unsafe { packed.as_ptr().byte_add(4) };
    let error = unsafe { read_points(misaligned, 1, 0, "target_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    assert!(error.message.contains("aligned"), "{}", error.message);
    let error = unsafe { read_points(null::<f32>(), 1, 0, "source_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error, FfiError::null("source_xyz"));
    let error = unsafe {
        read_points(
            packed.as_ptr(),
            usize::MAX / 8,
            0,
            "target_xyz",
            NonFinite::Reject,
        )
    }
    .unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
}

#[test]
fn non_finite_coordinates_name_the_first_bad_point() {
    let mut xyz = vec![0.5f32; 3 * 20];
    xyz[3 * 17 + 1] = f32::NAN;
    xyz[3 * 19] = f32::INFINITY;
    let error = unsafe { read_points(xyz.as_ptr(), 20, 0, "source_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::NonFiniteInput);
    assert!(
        error.message.starts_with("source_xyz[17] is NaN (y"),
        "{}",
        error.message
    );
}

#[test]
fn transforms_are_row_major_and_must_be_rigid() {
    let angle = 0.3f64;
    let (s, c) = angle.sin_cos();
    let row_major_t = [
        c, -s, 0.0, 1.0, s, c, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let rigid = unsafe { read_transform(row_major_t.as_ptr(), "init") }
        .unwrap()
        .unwrap();
    let matrix = rigid.transform;
    assert_eq!(matrix[(0, 3)], 1.0);
    assert!((matrix[(1, 0)] - s).abs() < 1e-15);
    let round_trip = row_major(&matrix);
    assert!(
        round_trip
            .iter()
            .zip(&row_major_t)
            .all(|(a, b)| (a - b).abs() < 1e-15)
    );
    assert!(rigid.correction < 1e-15);
    assert_eq!(unsafe { read_transform(null(), "init") }.unwrap(), None);

    let mut bad = row_major_t;
    bad[0] = 2.0 * c;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("orthonormal"), "{}", error.message);
    let mut bad = row_major_t;
    bad[12] = 1.0;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("last row"), "{}", error.message);
    // Rounding left by a general matrix inverse is accepted.
    let mut rounded = row_major_t;
    rounded[15] = 0.999_999_999_999_999_8;
    assert!(unsafe { read_transform(rounded.as_ptr(), "init") }.is_ok());
    let mut bad = row_major_t;
    bad[7] = f64::NAN;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("init[7] is NaN"), "{}", error.message);
    let mirror = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let error = unsafe { read_transform(mirror.as_ptr(), "init") }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    assert!(error.message.contains("reflection"), "{}", error.message);
}

/// Published ground truths are rounded (3DMatch's gt.log, GeoTransformer's gt.npy and PCL's
/// office matrix are orthonormal to 5e-5–7e-5): accepted within 1e-3, made exact, and the
/// correction reported in the summary; the transpose is suggested only when it would be valid.
#[test]
fn rounded_guesses_are_made_rigid_and_the_correction_reported() {
    let rotation = nalgebra::Rotation3::from_euler_angles(0.4, -0.7, 2.1);
    let mut t = Matrix4::identity();
    t.fixed_view_mut::<3, 3>(0, 0).copy_from(rotation.matrix());
    t[(0, 3)] = 1.25;
    // Printed with 4 decimals: orthonormal to ~5e-5, like the published matrices.
    let rounded = row_major(&t).map(|v| (v * 1e4).round() / 1e4);
    let as_matrix = Matrix4::from_row_slice(&rounded);
    let r = as_matrix.fixed_view::<3, 3>(0, 0).into_owned();
    let error = (r.transpose() * r - nalgebra::Matrix3::identity()).amax();
    assert!(error > 1e-5 && error < 2e-4, "{error}");
    let rigid = unsafe { read_transform(rounded.as_ptr(), "init") }
        .unwrap()
        .unwrap();
    let exact = rigid.transform.fixed_view::<3, 3>(0, 0).into_owned();
    assert!((exact.transpose() * exact - nalgebra::Matrix3::identity()).amax() < 1e-15);
    assert!(
        rigid.correction > 1e-6 && rigid.correction < 1e-4,
        "{}",
        rigid.correction
    );
    assert!((rigid.transform - t).amax() < 1e-4);

    // Through a registration: the summary carries the correction.
    let ctx = Context::new();
    let points: Vec<f32> = (0..300)
        .flat_map(|i| [(i % 7) as f32, (i % 11) as f32 * 0.5, (i % 13) as f32 * 0.3])
        .collect();
    let mut out = [0.0; 16];
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            points.as_ptr(),
            0,
            points.as_ptr(),
            0,
            100,
            rounded.as_ptr(),
            out.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::Ok, "{}", ctx.last_error());
    let mut summary = sie_summary::default();
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.init_correction, rigid.correction);
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            points.as_ptr(),
            0,
            points.as_ptr(),
            0,
            100,
            null(),
            out.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::Ok);
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.init_correction, 0.0);

    // Beyond 1e-3 it is not a rotation; transposing would not help, so no hint.
    let mut skewed = row_major(&t);
    skewed[1] += 2e-3;
    let error = unsafe { read_transform(skewed.as_ptr(), "init") }.unwrap_err();
    assert!(
        error.message.contains("orthonormal") && !error.message.contains("column-major"),
        "{}",
        error.message
    );
    // A rigid transform stored column-major: its transpose is valid, so the hint is given.
    let column_major: Vec<f64> = (0..16).map(|k| t[(k % 4, k / 4)]).collect();
    let error = unsafe { read_transform(column_major.as_ptr(), "init") }.unwrap_err();
    assert!(
        error.message.contains("last row") && error.message.contains("column-major"),
        "{}",
        error.message
    );
    // Scaled: neither it nor its transpose is rigid.
    let scaled = row_major(&(t * 2.0));
    let error = unsafe { read_transform(scaled.as_ptr(), "init") }.unwrap_err();
    assert!(!error.message.contains("column-major"), "{}", error.message);
}

#[test]
fn failed_registration_keeps_outputs_and_drops_the_previous_result() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut xyz = vec![0.0f32; 3 * 30];
    xyz[3 * 17] = f32::NAN;
    let mut out_t = [-1.0; 16];
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            xyz.as_ptr(),
            0,
            xyz.as_ptr(),
            0,
            30,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::NonFiniteInput);
    assert!(
        ctx.last_error().contains("source_xyz[17]"),
        "{}",
        ctx.last_error()
    );
    assert_eq!(out_t, [-1.0; 16]);
    assert!(!ctx.has_result());

    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            xyz.as_ptr(),
            0,
            xyz.as_ptr(),
            0,
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::TooFewPoints);
    assert_eq!(ctx.last_error(), "count is 0");

    let mut normals = vec![0.0f32; 3 * 30];
    xyz[3 * 17] = 0.0;
    let register_with = |normals: &[f32], out_t: &mut [f64; 16]| unsafe {
        sie_context_register_with_normals(
            ctx.0,
            xyz.as_ptr(),
            30,
            0,
            xyz.as_ptr(),
            30,
            0,
            normals.as_ptr(),
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(register_with(&normals, &mut out_t), sie_status::InvalidArgument);
    assert!(
        ctx.last_error().contains("every target normal is 0 0 0"),
        "{}",
        ctx.last_error()
    );
    normals[2] = 0.5;
    let status = unsafe {
        sie_context_register_with_normals(
            ctx.0,
            xyz.as_ptr(),
            30,
            0,
            xyz.as_ptr(),
            30,
            0,
            normals.as_ptr(),
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::InvalidArgument);
    assert!(
        ctx.last_error().contains("target normals[0] has length 0.5"),
        "{}",
        ctx.last_error()
    );
}

#[test]
fn buffers_are_sized_queried_and_never_partially_written() {
    let values = [1.0, 2.0, 3.0];
    let mut len = 0usize;
    unsafe {
        assert_eq!(
            write_buffer(null_mut::<f64>(), 0, &raw mut len, &values, "x"),
            Ok(())
        );
        assert_eq!(len, 3);
        let error = write_buffer(null_mut::<f64>(), 0, null_mut(), &values, "x").unwrap_err();
        assert_eq!(error.status, sie_status::NullArgument);
        let error = write_buffer(null_mut::<f64>(), 3, &raw mut len, &values, "x").unwrap_err();
        assert_eq!(error.status, sie_status::NullArgument);
        let mut small = [-9.0; 2];
        len = 77;
        let error = write_buffer(small.as_mut_ptr(), 2, &raw mut len, &values, "source points").unwrap_err();
        assert_eq!(error.status, sie_status::BufferTooSmall);
        assert_eq!(error.message, "capacity 2 is smaller than the 3 source points");
        assert_eq!((small, len), ([-9.0; 2], 77));
        let mut big = [-9.0; 5];
        assert_eq!(
            write_buffer(big.as_mut_ptr(), 5, &raw mut len, &values, "x"),
            Ok(())
        );
        assert_eq!((big, len), ([1.0, 2.0, 3.0, -9.0, -9.0], 3));
        assert_eq!(
            write_buffer(big.as_mut_ptr(), 5, null_mut(), &values, "x"),
            Ok(())
        );
    }
}

#[test]
fn getters_report_no_result_before_a_registration() {
    let ctx = Context::new();
    let mut summary = sie_summary::default();
    let mut model = sie_model::default();
    let mut len = 0;
    unsafe {
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::NoResult);
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_correspondences(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                null_mut(),
                null_mut(),
                null_mut(),
                null_mut(),
                0
            ),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_trace(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
    }
    assert!(ctx.last_error().starts_with("no result"), "{}", ctx.last_error());
}

#[test]
fn getters_copy_the_stored_result() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut summary = sie_summary::default();
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.sigma, [0.5, 0.0, 0.0]);
    assert_eq!(summary.beta, [0.25, 0.0, 0.0]);
    assert_eq!((summary.source_count, summary.correspondence_count), (3, 2));
    assert_eq!(summary.stop_reason, sie_stop_reason::IterationLimit as u32);
    assert_eq!(
        (summary.iterations, summary.histogram_count, summary.converged),
        (7, 1, false)
    );
    assert_eq!(summary.verdict, sie_verdict::Doubtful as u32);
    assert_eq!(summary.start, sie_start_kind::ScaleFreeLead as u32);
    assert_eq!(
        (
            summary.significance,
            summary.conditioning,
            summary.sigma_to_spacing,
            summary.margin,
            summary.runner_up_significance
        ),
        (41.5, 0.25, 0.75, 41.5 / 12.0, 12.0)
    );
    assert_eq!(
        (summary.starts_run, summary.hypotheses, summary.agreeing_starts),
        (3, 0, 2)
    );

    let mut probabilities = [0.0; 3];
    let mut correspondences = [0i64; 3];
    let mut len = 0;
    unsafe {
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, probabilities.as_mut_ptr(), 3, &mut len),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_get_correspondences(ctx.0, correspondences.as_mut_ptr(), 3, null_mut()),
            sie_status::Ok
        );
    }
    assert_eq!((probabilities, len), ([0.9, 0.0, 0.8], 3));
    assert_eq!(correspondences, [4, -1, 2]);

    let mut trace = [sie_trace_entry::default(); 2];
    assert_eq!(
        unsafe { sie_context_get_trace(ctx.0, trace.as_mut_ptr(), 2, &mut len) },
        sie_status::Ok
    );
    assert_eq!(len, 1);
    assert_eq!(
        (trace[0].iteration, trace[0].annealing, trace[0].correspondences),
        (1, true, 3)
    );
    // The transform reached by that update, row-major like every transform of the C API.
    assert_eq!(trace[0].transform[3], 1.5);
    assert_eq!(trace[0].transform[11], -0.5);
    assert_eq!(trace[0].transform[15], 1.0);
    assert_eq!(trace[1], sie_trace_entry::default());
}

/// Every verdict and start kind maps to its C value; the infinite values the core uses for "no
/// start ended elsewhere" and "zero spacing" come out finite (outputs are never inf or NaN).
#[test]
fn summary_encodes_verdicts_starts_and_unbounded_values_finitely() {
    let ctx = Context::new();
    let cases = [
        (
            Verdict::Good,
            StartKind::InitialGuess,
            sie_verdict::Good,
            sie_start_kind::InitialGuess,
        ),
        (
            Verdict::Doubtful,
            StartKind::NarrowBeta,
            sie_verdict::Doubtful,
            sie_start_kind::NarrowBeta,
        ),
        (
            Verdict::Unsupported,
            StartKind::Hypothesis,
            sie_verdict::Unsupported,
            sie_start_kind::Hypothesis,
        ),
    ];
    for (verdict, start, c_verdict, c_start) in cases {
        let mut result = sample_result();
        result.quality = Quality {
            verdict,
            significance: 7.0,
            conditioning: 0.5,
            sigma_to_spacing: f64::INFINITY,
            margin: f64::INFINITY,
        };
        result.search = SearchReport {
            start,
            hypotheses: 512,
            starts_run: 1,
            significance: 7.0,
            agreeing_starts: 1,
            runner_up_significance: 0.0,
        };
        ctx.inject_result(result);
        let mut summary = sie_summary::default();
        assert_eq!(
            unsafe { sie_context_get_summary(ctx.0, &mut summary) },
            sie_status::Ok
        );
        assert_eq!(
            (summary.verdict, summary.start),
            (c_verdict as u32, c_start as u32)
        );
        assert_eq!((summary.margin, summary.runner_up_significance), (0.0, 0.0));
        assert_eq!(summary.sigma_to_spacing, f64::MAX);
        assert_eq!((summary.starts_run, summary.hypotheses), (1, 512));
    }
    // A zeroed summary reads "no verdict", as its stop reason reads "none".
    assert_eq!(sie_summary::default().verdict, sie_verdict::None as u32);
}

/// The summary is caller-allocated: its layout is the ABI. The fields added in 0.2 follow the
/// 0.1 ones without moving them, u32 pairs before the doubles so no padding is left inside.
#[test]
fn summary_layout_is_the_documented_one() {
    use core::mem::{offset_of, size_of};
    assert_eq!(offset_of!(sie_summary, converged), 116);
    assert_eq!(offset_of!(sie_summary, verdict), 120);
    assert_eq!(offset_of!(sie_summary, start), 124);
    assert_eq!(offset_of!(sie_summary, significance), 128);
    assert_eq!(offset_of!(sie_summary, runner_up_significance), 160);
    assert_eq!(offset_of!(sie_summary, starts_run), 168);
    assert_eq!(offset_of!(sie_summary, agreeing_starts), 176);
    assert_eq!(size_of::<sie_summary>(), 184);
}

#[test]
fn histograms_are_copied_per_bin() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut model = sie_model::default();
    let mut counts = [-1.0; 4];
    let mut model_values = [-1.0; 4];
    let mut probability = [-1.0; 4];
    let none = null_mut();
    unsafe {
        assert_eq!(
            sie_context_get_histogram(ctx.0, 0, &mut model, none, none, none, none, 0),
            sie_status::Ok
        );
        assert_eq!(model.bins, 4);
        assert_eq!(
            (model.sigma, model.beta, model.range_hi, model.peak_found),
            (0.5, 0.25, 2.0, true)
        );
        assert_eq!(
            sie_context_get_histogram(ctx.0, 0, &mut model, counts.as_mut_ptr(), none, none, none, 3),
            sie_status::BufferTooSmall
        );
        assert_eq!(counts, [-1.0; 4]);
        assert_eq!(
            sie_context_get_histogram(ctx.0, 1, &mut model, none, none, none, none, 0),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("index 1"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                counts.as_mut_ptr(),
                none,
                model_values.as_mut_ptr(),
                probability.as_mut_ptr(),
                4
            ),
            sie_status::Ok
        );
    }
    assert_eq!(counts, [9.0, 7.0, 2.0, 1.0]);
    assert_eq!(probability, [0.99, 0.9, 0.4, 0.1]);
    // Bin centres 0.25, 0.75, ...: G(x) = 10·exp(-(x/0.5)²/2), without β.
    let expected = 10.0 * (-0.5f64 * 0.25).exp();
    assert!((model_values[0] - expected).abs() < 1e-12, "{}", model_values[0]);
}

#[test]
fn estimate_rejects_bad_input_before_running() {
    let ctx = Context::new();
    let mut residuals = vec![0.1; 12];
    let mut probabilities = [-1.0; 4];
    let run = |residuals: &[f64], rows, cols, scales: *const f64, beta, out: &mut [f64]| unsafe {
        sie_estimate_inliers(
            ctx.0,
            residuals.as_ptr(),
            rows,
            cols,
            scales,
            beta,
            out.as_mut_ptr(),
            null_mut(),
            0,
            null_mut(),
        )
    };
    assert_eq!(
        run(&residuals, 0, 3, null(), 0.0, &mut probabilities),
        sie_status::TooFewPoints
    );
    assert_eq!(
        run(&residuals, 4, 0, null(), 0.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    assert_eq!(
        run(&residuals, 4, 3, null(), -1.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    let scales = [1.0, 1.0, 0.0, 1.0];
    assert_eq!(
        run(&residuals, 4, 3, scales.as_ptr(), 0.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    assert!(ctx.last_error().contains("row_scales[2]"), "{}", ctx.last_error());
    // Finite but too large to square is no longer refused (the estimate rescales; a fuzzer
    // once found σ = inf from such input): four rows are too few, whatever their magnitude.
    residuals[5] = 2e152;
    assert_eq!(
        run(&residuals, 4, 3, null(), 0.0, &mut probabilities),
        sie_status::TooFewPoints
    );
    residuals[5] = 0.1;
    residuals[7] = f64::NEG_INFINITY;
    assert_eq!(
        run(&residuals, 4, 3, null(), 0.0, &mut probabilities),
        sie_status::NonFiniteInput
    );
    assert_eq!(
        ctx.last_error(),
        "residuals[7] is -inf (row index 2, column index 1, from 0)"
    );
    let status = unsafe {
        sie_estimate_inliers(
            ctx.0,
            null(),
            4,
            3,
            null(),
            0.0,
            probabilities.as_mut_ptr(),
            null_mut(),
            0,
            null_mut(),
        )
    };
    assert_eq!(status, sie_status::NullArgument);
    assert_eq!(ctx.last_error(), "residuals is NULL");
    assert_eq!(probabilities, [-1.0; 4]);
}

/// Packed float triples of a synthetic room scene, for full registrations through the ABI.
fn packed(points: &[crate::geometry::Point]) -> Vec<f32> {
    points.iter().flat_map(|p| p.map(|v| v as f32)).collect()
}

#[test]
fn prepared_target_arguments_are_checked_and_outputs_untouched() {
    let ctx = Context::new();
    let xyz = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let mut target: *mut sie_target = null_mut();
    let mut transform = [7.0; 16];
    // SAFETY (all calls): valid arrays or NULL, as each contract allows.
    unsafe {
        assert_eq!(
            sie_context_prepare_target(null_mut(), xyz.as_ptr(), 4, 0, null(), 0, &mut target),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 4, 0, null(), 0, null_mut()),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("out_target"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 0, 0, null(), 0, &mut target),
            sie_status::TooFewPoints
        );
        let non_unit = [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5];
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 4, 0, non_unit.as_ptr(), 0, &mut target),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("normals[3]"), "{}", ctx.last_error());
        assert!(target.is_null(), "not written on error");
        assert_eq!(
            sie_context_prepare_target_d(ctx.0, [0.0f64; 12].as_ptr(), 4, 0, null(), 0, &mut target),
            sie_status::Ok
        );
        assert_eq!(sie_target_point_count(target), 4);
        assert_eq!(
            sie_context_register_to(ctx.0, xyz.as_ptr(), 4, 0, null(), null(), transform.as_mut_ptr()),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("target"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_register_to(ctx.0, xyz.as_ptr(), 2, 0, target, null(), transform.as_mut_ptr()),
            sie_status::TooFewPoints
        );
        assert_eq!(transform, [7.0; 16]);
        assert_eq!(
            sie_target_estimate_normals(target, 1025),
            sie_status::InvalidArgument
        );
        sie_target_free(target);
    }
}

#[test]
fn contexts_on_several_threads_share_one_prepared_target() {
    let scene = crate::synthetic::room_scene(3_000, 0.01, 31);
    let (source, target_points) = (packed(&scene.source), packed(&scene.target));
    let serial = Context::new();
    let mut expected = [0.0; 16];
    let mut target: *mut sie_target = null_mut();
    // SAFETY: packed arrays of the stated counts; outputs valid.
    unsafe {
        assert_eq!(sie_context_set_threads(serial.0, 1), sie_status::Ok);
        assert_eq!(
            sie_context_register(
                serial.0,
                source.as_ptr(),
                3_000,
                0,
                target_points.as_ptr(),
                3_000,
                0,
                null(),
                expected.as_mut_ptr()
            ),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_prepare_target(serial.0, target_points.as_ptr(), 3_000, 0, null(), 0, &mut target),
            sie_status::Ok
        );
    }
    // The pointer crosses threads as an address: the target is Sync, and outlives the scope.
    let address = target as usize;
    let results: Vec<[f64; 16]> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..4)
            .map(|_| {
                let source = &source;
                scope.spawn(move || {
                    let ctx = Context::new();
                    let mut transform = [0.0; 16];
                    // SAFETY: live context and target; packed source of 3000 points.
                    let status = unsafe {
                        sie_context_set_threads(ctx.0, 1);
                        sie_context_register_to(
                            ctx.0,
                            source.as_ptr(),
                            3_000,
                            0,
                            address as *const sie_target,
                            null(),
                            transform.as_mut_ptr(),
                        )
                    };
                    assert_eq!(status, sie_status::Ok, "{}", ctx.last_error());
                    transform
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for transform in results {
        assert_eq!(transform.map(f64::to_bits), expected.map(f64::to_bits));
    }
    // SAFETY: created above, every user has returned.
    unsafe { sie_target_free(target) };
}

#[test]
fn warm_start_is_read_from_a_summary_and_checked() {
    let scene = crate::synthetic::room_scene(3_000, 0.01, 31);
    let (source, target) = (packed(&scene.source), packed(&scene.target));
    let ctx = Context::new();
    let mut transform = [0.0; 16];
    let mut summary = sie_summary::default();
    // SAFETY: live context, packed arrays of 3000 points, outputs valid.
    unsafe {
        assert_eq!(sie_context_set_threads(ctx.0, 1), sie_status::Ok);
        // `guess` NULL: the identity.
        let register = |guess: *const f64, transform: &mut [f64; 16]| {
            sie_context_register(
                ctx.0,
                source.as_ptr(),
                3_000,
                0,
                target.as_ptr(),
                3_000,
                0,
                guess,
                transform.as_mut_ptr(),
            )
        };
        assert_eq!(register(null(), &mut transform), sie_status::Ok);
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Ok);
        assert_eq!(sie_context_set_warm_start(ctx.0, &summary), sie_status::Ok);
        let warm = ctx.config().warm_start.expect("stored");
        assert_eq!(warm.sigma, summary.sigma[0]);
        assert_eq!(
            (warm.penalty, warm.inlier_fraction),
            (summary.penalty, summary.inlier_fraction)
        );
        // The same pair from its own answer: the warm run is kept.
        let guess = transform;
        assert_eq!(register(guess.as_ptr(), &mut transform), sie_status::Ok);
        let mut warm_summary = sie_summary::default();
        assert_eq!(sie_context_get_summary(ctx.0, &mut warm_summary), sie_status::Ok);
        assert_eq!(warm_summary.start, sie_start_kind::WarmStart as u32);
        assert_eq!(warm_summary.starts_run, 1);
        assert!(warm_summary.iterations < summary.iterations);

        // NULL clears it.
        assert_eq!(sie_context_set_warm_start(ctx.0, null()), sie_status::Ok);
        assert_eq!(ctx.config().warm_start, None);

        // A baseline's summary, and out-of-range values, are refused and change nothing.
        let before = ctx.config();
        let baseline = sie_summary {
            histogram_count: 0,
            ..summary
        };
        assert_eq!(
            sie_context_set_warm_start(ctx.0, &baseline),
            sie_status::InvalidArgument
        );
        assert!(
            ctx.last_error().contains("previous holds no SIE noise model"),
            "{}",
            ctx.last_error()
        );
        let negative = sie_summary {
            sigma: [-1.0, 0.0, 0.0],
            histogram_count: 1,
            ..summary
        };
        assert_eq!(
            sie_context_set_warm_start(ctx.0, &negative),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("sigma"), "{}", ctx.last_error());
        let misaligned = (&summary as *const sie_summary)
            .cast::<u8>()
            .wrapping_add(1)
            .cast::<sie_summary>();
        assert_eq!(
            sie_context_set_warm_start(ctx.0, misaligned),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("not aligned"), "{}", ctx.last_error());
        assert_eq!(ctx.config(), before);
    }
}
