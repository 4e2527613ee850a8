"""Dataclasses mirroring the C result structs, and their conversion from the ctypes ones."""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Tuple

import numpy as np

from . import _native
from ._enums import StartKind, StopReason, Verdict

INLIER_PROBABILITY = 0.5
"""A source point with a correspondence and P(inlier) at least this is an inlier (Registration)."""


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
    start, starts_run, agreeing_starts and hypotheses describe the search (Starts.AUTOMATIC,
    Starts.GLOBAL).
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

    The peers' names answer too, so code written for Open3D's or small_gicp's result reads this
    one (properties computed from the fields above; the table in the README lists them). An
    INLIER here is a source point that has a correspondence and P(inlier) >= INLIER_PROBABILITY
    (0.5): more likely an inlier than not. Open3D and small_gicp call a pair an inlier when it is
    closer than the max_correspondence_distance they were given; sie has no such distance.
    """

    transform: np.ndarray  # 4 x 4 float64, T_target_source
    summary: Summary
    inlier_probabilities: np.ndarray  # per source point (0 for unmatched)
    correspondences: np.ndarray  # matched target index per source point (-1 if unmatched)
    covariance: np.ndarray  # 6 x 6 Cov(d), d = (rotation vector, translation), target frame
    information: np.ndarray  # 6 x 6, inverse of covariance where the pose is constrained

    # ---- Open3D's RegistrationResult and small_gicp's RegistrationResult names ----------------

    @property
    def inlier_mask(self) -> np.ndarray:
        """Per source point: True for an inlier (matched, P(inlier) >= INLIER_PROBABILITY)."""
        mask: np.ndarray = (self.correspondences >= 0) & (self.inlier_probabilities >= INLIER_PROBABILITY)
        return mask

    @property
    def correspondence_set(self) -> np.ndarray:
        """Open3D's name: the inliers' pairs as an n x 2 int64 array, rows (source index, target
        index) in source order. Open3D's pairs are those closer than its distance gate;
        Open3D's tensor API gives a per-source-point array with -1 for none instead, which is
        np.where(result.inlier_mask, result.correspondences, -1) here."""
        sources = np.flatnonzero(self.inlier_mask)
        pairs: np.ndarray = np.column_stack((sources, self.correspondences[sources])).astype(np.int64, copy=False)
        return pairs

    @property
    def num_inliers(self) -> int:
        """small_gicp's name: the number of inliers (rows of correspondence_set). small_gicp
        counts the pairs within its max_correspondence_distance."""
        return int(np.count_nonzero(self.inlier_mask))

    @property
    def fitness(self) -> float:
        """Open3D's name: inliers / source points (0 for an empty source), as Open3D's "number of
        inlier correspondences / number of source points". summary.inlier_fraction is the soft
        version: the mean P(inlier) over the source points."""
        count = self.summary.source_count
        return self.num_inliers / count if count else 0.0

    @property
    def inlier_rmse(self) -> float:
        """Open3D's name for summary.rmse: sqrt(sum P*r**2 / sum P) over the matched points, r
        the metric's residual (the distance to the target point's tangent plane for
        point-to-plane), in input units. Not Open3D's quantity exactly: Open3D averages the
        squared point-to-point distances of its correspondence_set with equal weights; the C API
        returns no per-point residuals to compute that from."""
        return float(self.summary.rmse)

    @property
    def transformation(self) -> np.ndarray:
        """Open3D's name for transform (4 x 4 float64, T_target_source)."""
        return self.transform

    @property
    def T_target_source(self) -> np.ndarray:  # noqa: N802 - small_gicp's spelling
        """small_gicp's name for transform (4 x 4 float64: p_target = T @ p_source)."""
        return self.transform

    @property
    def converged(self) -> bool:
        """Open3D's (tensor API) and small_gicp's name for summary.converged: sie stopped by
        its own convergence criteria (not the iteration cap, not a cancellation). Check
        summary.verdict too: a converged pose can still be wrong."""
        return bool(self.summary.converged)

    @property
    def num_iterations(self) -> int:
        """Open3D's (tensor API) name for summary.iterations: updates made, by every start
        (Starts.AUTOMATIC runs several)."""
        return int(self.summary.iterations)

    @property
    def iterations(self) -> int:
        """small_gicp's name for summary.iterations (updates of every start). small_gicp stores
        the 0-based index of its last iteration, one less than the updates it made."""
        return int(self.summary.iterations)

    @property
    def H(self) -> np.ndarray:  # noqa: N802 - small_gicp's spelling
        """small_gicp's name for information (6 x 6, rotation first, then translation, as
        small_gicp orders them). Two differences from small_gicp's H:

        - the frame: sie's d perturbs on the LEFT in the target frame, T = Exp(d) @ transform;
          small_gicp's on the right in the source frame, T = transform @ Exp(d_s). With R, t the
          rotation and translation of transform, d = Ad @ d_s, Ad = [[R, 0], [hat(t) @ R, R]],
          so small_gicp's frame is Ad.T @ H @ Ad;
        - the scale: sie's is the inverse of the pose covariance, measured from the inliers'
          residuals and noise (units 1/rad**2, 1/length**2, ...); small_gicp's is its last
          Gauss-Newton Hessian sum J.T @ W @ J (W = identity for its point-to-point ICP; its
          GICP weighs by the points' combined covariances), not divided by a noise variance.

        small_gicp's b (gradient) and error (cost) have no counterpart: the library does not
        return them."""
        return self.information


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
