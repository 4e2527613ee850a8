//! The setters: valid values stored, rejected ones leave the configuration as it was, and the
//! documented defaults.

use super::*;
use crate::cost::CostFunction;
use crate::registration::{Metric, Starts};
use crate::sie::{HistogramMode, NoiseShape};

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
        assert_eq!(ctx.config().sie.noise_shape, NoiseShape::Estimated);
        assert_eq!(sie_context_set_noise_shape(ctx.0, 1.0), sie_status::Ok);
        assert_eq!(ctx.config().sie.noise_shape, NoiseShape::Fixed(1.0));
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
        assert_eq!(
            sie_context_set_starts(ctx.0, sie_starts::Global as u32),
            sie_status::Ok
        );
        assert_eq!(ctx.config().starts, Starts::Global);
        assert_eq!(sie_context_set_starts(ctx.0, 3), sie_status::InvalidArgument);
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
            sie_context_set_starts(ctx.0, 3),
            "starts = 3 is not a known value (valid: 0..=2)",
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
    assert_eq!(config.sie.noise_shape, NoiseShape::Fixed(2.0));
    assert_eq!(config.sie.histogram, HistogramMode::Pooled);
    assert_eq!((config.initial_beta, config.beta_shrink), (None, 0.5));
    assert_eq!(config.max_correspondences, 0);
    assert_eq!(config.normal_neighbours, 10);
    assert_eq!(config.threads, 0);
    assert_eq!(config.seed, 0x5EED);
    assert!(!config.record_trace);
    assert_eq!(config.starts, Starts::Automatic);
}
