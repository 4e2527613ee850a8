"""Dataclasses mirroring the C result structs, and their conversion from the ctypes ones."""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Tuple

import numpy as np

from . import _native
from ._enums import StartKind, StopReason, Verdict


@dataclass(frozen=True)
class Summary:
    """Summary of a registration (sie_summary).

    Units of sigma and beta: SIE fits the histogram of each residual divided by its pair's
    noise scale F. With the constant noise model and no noise callback F = 1, so sigma is in
    the input's units (metres for metric scans). With a noise callback F is
    sqrt(sigma_source**2 + sigma_target**2) of the values it returned for the two matched
    points, and with NoiseModel.QUADRATIC_DEPTH the same with sigma = z**2: sigma is then a
    multiple of those values (about 1 when the callback returns the sensor's noise in input
    units; a residual unit per callback unit in general). rmse is always in input units.
    inlier_fraction is sum of P(inlier) over the source points / their number (unmatched
    points count 0), the same quantity as TraceEntry.inlier_fraction.

    verdict says how far to trust the pose (converged only says the iterations settled): GOOD,
    DOUBTFUL or UNSUPPORTED, from significance (of the inlier cluster against chance, nats; 0:
    nothing stands out), conditioning (how well the inliers constrain the pose, 0..1; GOOD
    needs >= 0.02), sigma_to_spacing (fitted sigma over the target points' spacing; clouds
    only, GOOD needs <= 1) and margin (significance over runner_up_significance, that of the
    best start that ended at another pose; GOOD needs >= 2; 0 when no start ended elsewhere).
    start, starts_run, agreeing_starts and hypotheses describe the search (Starts.AUTOMATIC).
    iterations counts the updates of every start; max_iterations caps each start.
    """

    sigma: Tuple[float, float, float]
    beta: Tuple[float, float, float]
    penalty: float
    noise_shape: float
    inlier_fraction: float
    rmse: float
    init_correction: float  # how much the initial guess was corrected to be exactly rigid
    source_count: int
    correspondence_count: int
    iterations: int
    stop_reason: StopReason
    histogram_count: int
    converged: bool
    verdict: Verdict
    significance: float
    conditioning: float
    sigma_to_spacing: float
    margin: float
    start: StartKind
    starts_run: int
    agreeing_starts: int
    hypotheses: int
    runner_up_significance: float


@dataclass(frozen=True)
class Registration:
    """What Context.align* returns.

    covariance and information (6 x 6 float64, information the inverse of covariance where the
    data constrain the pose) describe the uncertainty of transform: it is perturbed on the
    left, T = expm(hat(d)) @ transform, with d = (w, v), the rotation vector w in radians
    FIRST (rows and columns 0-2), then the translation v (3-5), both in the target frame and
    in the input's units. Directions the inliers leave free (sliding along a plane) get a far
    larger variance and a far smaller information than the constrained ones (with estimated
    normals only by about (point spacing / noise)**2). Both are zeros when the result had too
    few weighted residuals to measure a variance.
    """

    transform: np.ndarray  # 4 x 4 float64, T_target_source
    summary: Summary
    inlier_probabilities: np.ndarray  # per source point (0 for unmatched)
    correspondences: np.ndarray  # matched target index per source point (-1 if unmatched)
    covariance: np.ndarray  # 6 x 6 Cov(d), d = (rotation vector, translation), target frame
    information: np.ndarray  # 6 x 6, inverse of covariance where the pose is constrained


@dataclass(frozen=True)
class Model:
    """One fitted SIE histogram model (sie_model)."""

    mu: float
    sigma: float
    alpha: float
    noise_shape: float
    beta: float
    penalty: float
    range_lo: float
    range_hi: float
    mean_inlier_probability: float
    bins: int
    samples_in_range: int
    peak_found: bool


@dataclass(frozen=True)
class Histogram:
    model: Model
    counts: np.ndarray
    smoothed: np.ndarray
    model_values: np.ndarray
    probability: np.ndarray


@dataclass(frozen=True)
class TraceEntry:
    """One iteration (sie_trace_entry): what a progress callback receives and trace() lists."""

    iteration: int
    sigma: float
    beta: float
    penalty: float
    inlier_fraction: float
    rmse: float
    translation_change: float
    rotation_change: float
    correspondences: int
    annealing: bool
    transform: np.ndarray  # 4 x 4 T_target_source reached by this update, for a viewer


@dataclass(frozen=True)
class InlierEstimate:
    probabilities: np.ndarray
    models: List[Model]


def _model(raw: _native.sie_model) -> Model:
    return Model(
        raw.mu, raw.sigma, raw.alpha, raw.noise_shape, raw.beta, raw.penalty, raw.range_lo, raw.range_hi,
        raw.mean_inlier_probability, int(raw.bins), int(raw.samples_in_range), bool(raw.peak_found),
    )


def _trace_entry(e: _native.sie_trace_entry) -> TraceEntry:
    transform = np.array(e.transform, dtype=np.float64).reshape(4, 4)  # row-major in C
    return TraceEntry(int(e.iteration), e.sigma, e.beta, e.penalty, e.inlier_fraction, e.rmse,
                      e.translation_change, e.rotation_change, int(e.correspondences), bool(e.annealing),
                      transform)
