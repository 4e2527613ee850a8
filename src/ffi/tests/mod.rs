//! Boundary, NULL handling, input reading and result getters of the C ABI, exercised through
//! the exported functions. Results are injected into the context so these tests do not depend
//! on the registration driver; tests/c_api.rs covers full registrations from C. One file a
//! topic; the context they use and the result they inject are here.

mod boundary;
mod estimate;
mod inputs;
mod odometry;
mod results;
mod settings;
mod status_and_enums;
mod targets_and_warm_starts;

use core::ffi::CStr;

use nalgebra::Matrix4;

use super::*;
use crate::registration::{
    Quality, RegistrationResult, SearchReport, StartKind, StopReason, TraceEntry, Verdict,
};
use crate::sie::HistogramModel;
use crate::sie::shape::GeneralisedGaussian;

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
        uncertainty: crate::PoseUncertainty::UNKNOWN,
        quality: Quality {
            verdict: Verdict::Doubtful,
            significance: 41.5,
            conditioning: 0.25,
            sigma_to_spacing: 0.75,
            loose_direction: None,
            scaled_source: None,
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
