"""Point-cloud registration with Statistical Inlier Estimation (SIE), over libsie's C ABI.

    import sie
    result = sie.align(source, target)         # N x 3 arrays or open3d PointClouds -> sie.Registration
    result.transform                           # 4 x 4, T_target_source: p_target = T @ p_source
    result.summary.verdict                     # Verdict.GOOD: use it; DOUBTFUL: check; UNSUPPORTED: reject
    with sie.Context(max_iterations=100) as ctx:   # settings, callbacks, trace, histograms
        result = ctx.align(source, target)

Clouds: N x 3 arrays (N x 4 too, e.g. padded float32; the first three columns are used) of real
numbers, or open3d.geometry.PointCloud / open3d.t.geometry.PointCloud (a target's normals are
then used for point-to-plane). float32 or float64 arrays with contiguous columns are passed to
the library in place (no copy), whatever their row stride; anything else is converted first. A
pair of clouds is registered in float32 when both are float32, otherwise in float64. A 3 x N
array (points as columns), other column counts, and complex, string, object or boolean arrays
are refused with ValueError / TypeError.

Failures raise SieError with the library's status and message. A cancelled registration
(Context.cancel(), or a progress callback returning False) is not a failure: it returns the
transform reached, with summary.stop_reason == StopReason.CANCELLED. A Context is used by one
thread at a time (except cancel(), callable from any thread); distinct Contexts are independent.
The library is called through ctypes.CDLL, which releases the GIL during each call: Contexts in
different threads register in parallel.
"""

from __future__ import annotations

import ctypes
import enum
from dataclasses import dataclass
from typing import Any, Callable, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import _native

_lib = _native.load_library()

__all__ = [
    "Cloud",
    "align",
    "Context",
    "CostFunction",
    "HistogramMode",
    "Histogram",
    "InlierEstimate",
    "Metric",
    "Model",
    "NoiseModel",
    "Registration",
    "SieError",
    "StartKind",
    "Starts",
    "Target",
    "Status",
    "StopReason",
    "Summary",
    "TraceEntry",
    "Verdict",
    "library_version",
]


class _NamedEnum(enum.IntEnum):
    """An IntEnum that prints as its name (StopReason.CONVERGED), as on every Python version."""

    def __str__(self) -> str:
        return f"{type(self).__name__}.{self.name}"

    def __format__(self, spec: str) -> str:
        return format(str(self), spec)


class Status(_NamedEnum):
    OK = 0
    NULL_ARGUMENT = 1
    INVALID_ARGUMENT = 2
    NON_FINITE_INPUT = 3
    TOO_FEW_POINTS = 4
    CALLBACK_FAILED = 5
    NO_RESULT = 6
    BUFFER_TOO_SMALL = 7
    BUSY = 8
    CANCELLED = 9
    OUT_OF_MEMORY = 10
    PANIC = 100


class CostFunction(_NamedEnum):
    SIE = 0
    L2 = 1
    TRUNCATED_L2 = 2
    LP = 3
    STUDENT_T = 4
    HUBER = 5
    CAUCHY = 6
    GEMAN_MCCLURE = 7
    TUKEY = 8


class Metric(_NamedEnum):
    POINT_TO_POINT = 0
    POINT_TO_PLANE = 1


class NoiseModel(_NamedEnum):
    CONSTANT = 0
    QUADRATIC_DEPTH = 1


class HistogramMode(_NamedEnum):
    POOLED = 0
    PER_COLUMN = 1


class StopReason(_NamedEnum):
    NONE = 0
    CONVERGED = 1
    ITERATION_LIMIT = 2
    DEGENERATE = 3
    CANCELLED = 4


class Starts(_NamedEnum):
    """Where SIE starts (Context.set_starts / starts=...)."""

    AUTOMATIC = 0  # several starts, the most significant result is kept (the default)
    INITIAL_GUESS = 1  # one run from the initial guess (the paper's method)


class Verdict(_NamedEnum):
    """How far to trust a registration (Summary.verdict)."""

    NONE = 0  # no result
    GOOD = 1  # the evidence supports the pose: use it
    DOUBTFUL = 2  # registered, but some evidence is weak: check it, or retry from another guess
    UNSUPPORTED = 3  # no inlier cluster stands out from the background: reject the pose


class StartKind(_NamedEnum):
    """Which start the returned transform came from (Summary.start)."""

    INITIAL_GUESS = 0
    NARROW_BETA = 1
    SCALE_FREE_LEAD = 2
    HYPOTHESIS = 3
    WARM_START = 4


class Cloud(_NamedEnum):
    SOURCE = 0
    TARGET = 1


def _enum_or_int(kind: Any, value: int) -> Any:
    try:
        return kind(value)
    except ValueError:
        return int(value)


class SieError(Exception):
    """A call into libsie failed: `status` (Status) and the library's `message`."""

    def __init__(self, status: int, message: str):
        self.status = _enum_or_int(Status, status)
        self.message = message
        text = _lib.sie_status_str(int(status)).decode()
        super().__init__(f"{text}: {message}" if message else text)


def library_version() -> str:
    """The loaded library's version, e.g. "0.2.0"."""
    return str(_lib.sie_version_string().decode())


def _package_version() -> str:
    """The installed distribution's version; the wheel is versioned with the library it carries."""
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:  # pragma: no cover - Python < 3.8
        return library_version()
    try:
        return version("sie")
    except PackageNotFoundError:  # run from a source checkout
        return library_version()


__version__ = _package_version()


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
    needs >= 1e-3), sigma_to_spacing (fitted sigma over the target points' spacing; clouds
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
    """What Context.align* returns."""

    transform: np.ndarray  # 4 x 4 float64, T_target_source
    summary: Summary
    inlier_probabilities: np.ndarray  # per source point (0 for unmatched)
    correspondences: np.ndarray  # matched target index per source point (-1 if unmatched)


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


class _Points:
    """An N x k array as the library reads it: pointer, count, byte stride, element type.
    Holds a reference to the array (the original or a converted copy) while in use."""

    def __init__(self, array: np.ndarray, dtype: npt.DTypeLike) -> None:
        self.array = array
        self.dtype = np.dtype(dtype)
        self.count = array.shape[0]
        self.stride = array.strides[0]
        ctype = ctypes.c_float if self.dtype == np.float32 else ctypes.c_double
        self.pointer = array.ctypes.data_as(ctypes.POINTER(ctype))

    @property
    def address(self) -> int:
        return self.array.ctypes.data


def _real_array(values: Any, name: str) -> np.ndarray:
    """np.asarray(values), refusing what is not real numbers (as numpy users expect)."""
    array = np.asarray(values)
    if array.dtype.kind not in "fiu":
        kind = {"c": "complex", "b": "boolean", "U": "string", "S": "bytes", "O": "object"}.get(
            array.dtype.kind, "non-numeric")
        raise TypeError(f"{name} has {kind} dtype {array.dtype}; coordinates must be real numbers "
                        "(float32 or float64, integers are converted)")
    return array


def _points(values: Any, name: str, dtype: npt.DTypeLike) -> _Points:
    """`values` as points of `dtype` (float32 or float64) without copying when the memory already
    has that layout: native-endian `dtype`, contiguous columns, a positive row stride."""
    array = _real_array(values, name)
    if array.ndim != 2 or array.shape[1] not in (3, 4):
        shape = tuple(array.shape)
        if array.ndim == 2 and array.shape[0] in (3, 4):
            hint = f"; it looks like {array.shape[0]} x N, one point per column: pass {name}.T"
        elif array.ndim == 2 and array.shape[1] > 4:
            hint = f"; for more columns pass {name}[:, :3] (a view, not copied)"
        else:
            hint = ""
        raise ValueError(f"{name} must be an N x 3 array of points (N x 4 also works); got shape {shape}{hint}")
    dtype = np.dtype(dtype)
    item = dtype.itemsize
    in_place = (
        array.dtype == dtype
        and array.dtype.isnative
        and array.strides[1] == item
        and array.strides[0] >= 3 * item
        and array.strides[0] % item == 0
        and array.ctypes.data % item == 0
    )
    if not in_place:
        array = np.ascontiguousarray(array[:, :3], dtype=dtype)
    return _Points(array, dtype)


def _open3d_cloud(cloud: Any) -> Optional[Tuple[np.ndarray, Optional[np.ndarray]]]:
    """(points, normals or None) of an open3d.geometry.PointCloud (legacy, points as a float64
    view) or open3d.t.geometry.PointCloud (tensor); None for anything else. Open3D itself is
    never imported here: only its objects are recognised."""
    if not type(cloud).__module__.startswith("open3d"):
        return None
    tensor_attributes = getattr(cloud, "point", None)
    if tensor_attributes is not None and hasattr(tensor_attributes, "positions"):
        points = tensor_attributes.positions.cpu().numpy()
        normals = tensor_attributes.normals.cpu().numpy() if "normals" in tensor_attributes else None
        return points, normals
    if hasattr(cloud, "points") and hasattr(cloud, "has_normals"):
        points = np.asarray(cloud.points)
        normals = np.asarray(cloud.normals) if cloud.has_normals() else None
        return points, normals
    raise TypeError(f"{type(cloud).__module__}.{type(cloud).__name__} is not a point cloud sie can read")


def _cloud_dtype(*arrays: Any) -> type:
    """float32 when every input is float32 (the float entry points, zero copy), else float64."""
    return np.float32 if all(np.asarray(a).dtype == np.float32 for a in arrays) else np.float64


def _transform_in(init: Optional[npt.ArrayLike]) -> Optional[np.ndarray]:
    if init is None:
        return None
    matrix = np.ascontiguousarray(_real_array(init, "init"), dtype=np.float64)
    if matrix.shape != (4, 4):
        raise ValueError(f"init must be a 4 x 4 matrix, got shape {matrix.shape}")
    return matrix


def _double_pointer(array: Optional[np.ndarray]) -> Any:
    return None if array is None else array.ctypes.data_as(_native.c_double_p)


NoiseCallback = Callable[[Cloud, np.ndarray], npt.ArrayLike]
ProgressCallback = Callable[[TraceEntry], Optional[bool]]
#: A cloud: an N x 3 (or N x 4) array-like of real numbers, or an Open3D point cloud.
CloudLike = Union[npt.ArrayLike, Any]


def _trace_entry(e: _native.sie_trace_entry) -> TraceEntry:
    transform = np.array(e.transform, dtype=np.float64).reshape(4, 4)  # row-major in C
    return TraceEntry(int(e.iteration), e.sigma, e.beta, e.penalty, e.inlier_fraction, e.rmse,
                      e.translation_change, e.rotation_change, int(e.correspondences), bool(e.annealing),
                      transform)


class Target:
    """A prepared target cloud (sie_target): its kd-tree and normals built once for many
    Context.align(source, target) calls (odometry onto the previous frame, scan-to-map), with
    the same results as aligning onto the points themselves. Immutable: contexts on several
    threads may align onto one Target at once (the library releases the GIL).

    Target(points, normals=None, normal_neighbours=10, skip_non_finite=False), or
    Context.prepare_target(points, normals) with that context's settings. The points are
    copied. Freed by close() or the garbage collector."""

    def __init__(self, points: CloudLike, normals: Optional[npt.ArrayLike] = None,
                 normal_neighbours: int = 10, skip_non_finite: bool = False) -> None:
        self._handle = ctypes.c_void_p(None)
        with Context(normal_neighbours=normal_neighbours, skip_non_finite=skip_non_finite) as context:
            self._handle = context._prepare(points, normals)

    @classmethod
    def _adopt(cls, handle: ctypes.c_void_p) -> "Target":
        target = cls.__new__(cls)
        target._handle = handle
        return target

    def __len__(self) -> int:
        """Points the target was made from."""
        return int(_lib.sie_target_point_count(self._handle))

    def estimate_normals(self, threads: int = 0) -> None:
        """Estimates every normal not estimated yet (threads: 0 = one per core), so that no later
        align() pays for them. Results are the same either way."""
        if not self._handle.value:
            raise SieError(Status.NULL_ARGUMENT, "the target is closed")
        status = _lib.sie_target_estimate_normals(self._handle, int(threads))
        if status != Status.OK:
            raise SieError(status, f"threads = {threads}; at most 1024")

    def close(self) -> None:
        """Frees the target; no align() may be using it."""
        handle = getattr(self, "_handle", None)
        if handle is not None and handle.value:
            _lib.sie_target_free(handle)
            self._handle = ctypes.c_void_p(None)

    def __enter__(self) -> "Target":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


class Context:
    """A libsie context: configuration, noise callback, last result.

    Settings may be given as keyword arguments, e.g. Context(metric=Metric.POINT_TO_POINT,
    max_iterations=50); each maps to the set_<name> method. cost takes CostFunction or
    (CostFunction, parameter)."""

    def __init__(self, **settings: Any) -> None:
        handle = _lib.sie_context_new()
        if not handle:
            raise MemoryError("sie_context_new returned NULL")
        self._handle = ctypes.c_void_p(handle)
        # The ctypes callback objects the library points at, and what a callback raised.
        self._noise_function: Optional[Any] = None
        self._progress_function: Optional[Any] = None
        self._callback_error: Optional[BaseException] = None
        for name, value in settings.items():
            if name == "cost":
                cost, parameter = value if isinstance(value, tuple) else (value, 0.0)
                self.set_cost_function(cost, parameter)
                continue
            setter = getattr(self, f"set_{name}", None)
            if setter is None:
                raise TypeError(f"unknown setting {name!r}")
            if isinstance(value, tuple):
                setter(*value)
            else:
                setter(value)

    # ---- lifetime ----------------------------------------------------------------------

    def close(self) -> None:
        """Frees the context (also done by the garbage collector); further calls fail."""
        handle = getattr(self, "_handle", None)
        if handle is not None and handle.value:
            _lib.sie_context_free(handle)
            self._handle = ctypes.c_void_p(None)
        # Only after the library no longer points at them.
        self._noise_function = None
        self._progress_function = None

    def cancel(self) -> None:
        """Asks the running registration to stop after its current iteration (or, if none runs,
        the next one after its first). May be called from any thread while align*() runs."""
        handle = getattr(self, "_handle", None)
        if handle is not None and handle.value:
            _lib.sie_context_cancel(handle)

    def __enter__(self) -> "Context":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

    # ---- errors ------------------------------------------------------------------------

    def _check(self, status: int) -> None:
        if status != Status.OK:
            raise SieError(status, _lib.sie_context_last_error(self._handle).decode(errors="replace"))

    def _run(self, status: int) -> None:
        """_check for registrations: re-raises what a callback raised (it made the library return
        CALLBACK_FAILED or CANCELLED); a plain cancellation is a result, not an error."""
        error, self._callback_error = self._callback_error, None
        if error is not None and status in (Status.CALLBACK_FAILED, Status.CANCELLED):
            raise error
        if status != Status.CANCELLED:
            self._check(status)

    # ---- settings ----------------------------------------------------------------------

    def set_cost_function(self, cost: CostFunction, parameter: float = 0.0) -> "Context":
        self._check(_lib.sie_context_set_cost_function(self._handle, int(cost), float(parameter)))
        return self

    def set_metric(self, metric: Metric) -> "Context":
        self._check(_lib.sie_context_set_metric(self._handle, int(metric)))
        return self

    def set_starts(self, starts: Starts) -> "Context":
        """Starts.AUTOMATIC (the default) runs SIE from several starts and keeps the most
        significant result; Starts.INITIAL_GUESS runs once from the initial guess."""
        self._check(_lib.sie_context_set_starts(self._handle, int(starts)))
        return self

    def set_warm_start(self, previous: Optional[Summary]) -> "Context":
        """Starts the following registrations from the noise model of `previous`, an earlier SIE
        registration's Summary (None: start cold again). For sequences registered from good
        guesses; falls back to the full search by itself when the guess was bad
        (Summary.start is StartKind.WARM_START when the warm run was kept)."""
        if previous is None:
            self._check(_lib.sie_context_set_warm_start(self._handle, None))
            return self
        raw = _native.sie_summary()
        raw.sigma[:] = list(previous.sigma)
        raw.beta[:] = list(previous.beta)
        raw.penalty = previous.penalty
        raw.noise_shape = previous.noise_shape
        raw.inlier_fraction = previous.inlier_fraction
        raw.histogram_count = previous.histogram_count
        self._check(_lib.sie_context_set_warm_start(self._handle, ctypes.byref(raw)))
        return self

    def set_max_iterations(self, max_iterations: int) -> "Context":
        """Caps the updates of each start (Summary.iterations counts those of all starts)."""
        self._check(_lib.sie_context_set_max_iterations(self._handle, int(max_iterations)))
        return self

    def set_convergence(self, translation: float, rotation_radians: float) -> "Context":
        self._check(_lib.sie_context_set_convergence(self._handle, float(translation), float(rotation_radians)))
        return self

    def set_noise_model(self, model: NoiseModel) -> "Context":
        self._check(_lib.sie_context_set_noise_model(self._handle, int(model)))
        return self

    def set_noise_shape(self, p: float) -> "Context":
        self._check(_lib.sie_context_set_noise_shape(self._handle, float(p)))
        return self

    def set_histogram_mode(self, mode: HistogramMode) -> "Context":
        self._check(_lib.sie_context_set_histogram_mode(self._handle, int(mode)))
        return self

    def set_regularizer(self, initial_beta: float, shrink: float) -> "Context":
        self._check(_lib.sie_context_set_regularizer(self._handle, float(initial_beta), float(shrink)))
        return self

    def set_max_correspondences(self, max_correspondences: int) -> "Context":
        self._check(_lib.sie_context_set_max_correspondences(self._handle, int(max_correspondences)))
        return self

    def set_normal_neighbours(self, neighbours: int) -> "Context":
        self._check(_lib.sie_context_set_normal_neighbours(self._handle, int(neighbours)))
        return self

    def set_threads(self, threads: int) -> "Context":
        self._check(_lib.sie_context_set_threads(self._handle, int(threads)))
        return self

    def set_seed(self, seed: int) -> "Context":
        self._check(_lib.sie_context_set_seed(self._handle, int(seed)))
        return self

    def set_trace(self, enabled: bool) -> "Context":
        self._check(_lib.sie_context_set_trace(self._handle, bool(enabled)))
        return self

    def set_skip_non_finite(self, enabled: bool) -> "Context":
        """Drop points with NaN/inf coordinates instead of failing; they get probability 0 and
        correspondence -1."""
        self._check(_lib.sie_context_set_skip_non_finite(self._handle, bool(enabled)))
        return self

    def set_skip_origin(self, enabled: bool) -> "Context":
        """Drop points at exactly 0 0 0 (depth sensors' invalid pixels) like non-finite ones."""
        self._check(_lib.sie_context_set_skip_origin(self._handle, bool(enabled)))
        return self

    def set_progress_callback(self, function: Optional[ProgressCallback]) -> "Context":
        """function(entry: TraceEntry) after every iteration, on the calling thread; returning
        False cancels the registration (None or True continue). Whatever it raises cancels it and
        is re-raised by align*(). None removes it."""
        if function is None:
            self._check(_lib.sie_context_set_progress_callback(self._handle, _native.PROGRESS_FN(), None))
            self._progress_function = None
            return self

        def trampoline(_user_data: Any, entry: Any) -> int:
            try:
                return 1 if function(_trace_entry(entry.contents)) is False else 0
            except BaseException as error:  # noqa: BLE001 - re-raised by _run after the call
                self._callback_error = error
                return 1

        callback = _native.PROGRESS_FN(trampoline)
        self._check(_lib.sie_context_set_progress_callback(self._handle, callback, None))
        self._progress_function = callback
        return self

    def set_noise_callback(self, function: Optional[NoiseCallback]) -> "Context":
        """Per-point noise: function(cloud, xyz) gets a Cloud and a read-only n x 3 float64 array
        (that cloud's points in its own frame, valid during the call only) and returns n sigmas
        (finite, > 0). Called once per cloud per registration, on the calling thread.
        Whatever it raises aborts the registration and is re-raised by align*(). None removes it.

        Each residual is then divided by F = sqrt(sigma_source**2 + sigma_target**2) of its two
        points, so Summary.sigma is in multiples of the returned values (about 1 when they are
        the sensor's noise in input units), not in input units; rmse stays in input units."""
        if function is None:
            self._check(_lib.sie_context_set_noise_callback(self._handle, _native.NOISE_FN(), None))
            self._noise_function = None
            return self

        def trampoline(_user_data: Any, cloud: int, xyz: Any, n: int, out_sigma: Any) -> int:
            # Nothing may propagate into the library (ctypes would print and return 0).
            try:
                points = np.ctypeslib.as_array(xyz, shape=(n, 3)) if n else np.empty((0, 3))
                points.flags.writeable = False
                sigma = np.asarray(function(_enum_or_int(Cloud, cloud), points), dtype=np.float64)
                if sigma.shape != (n,):
                    raise ValueError(f"the noise callback returned shape {sigma.shape}, expected ({n},)")
                if n:
                    np.ctypeslib.as_array(out_sigma, shape=(n,))[:] = sigma
                return 0
            except BaseException as error:  # noqa: BLE001 - re-raised by _run after the call
                self._callback_error = error
                return 1

        callback = _native.NOISE_FN(trampoline)
        self._check(_lib.sie_context_set_noise_callback(self._handle, callback, None))
        self._noise_function = callback  # the library holds a pointer to it: keep it alive
        return self

    # ---- registration ------------------------------------------------------------------

    def prepare_target(self, points: CloudLike, normals: Optional[npt.ArrayLike] = None) -> Target:
        """A Target for many align(source, target) calls, with this context's normal_neighbours
        and skip_non_finite. normals: N x 3 unit normals (0 0 0 for none), or None to estimate
        them; an Open3D cloud's own normals are used unless normals is given."""
        return Target._adopt(self._prepare(points, normals))

    def _prepare(self, points: CloudLike, normals: Optional[npt.ArrayLike]) -> ctypes.c_void_p:
        opened = _open3d_cloud(points)
        if opened is not None:
            points = opened[0]
            if normals is None:
                normals = opened[1]
        dtype = _cloud_dtype(points) if normals is None else _cloud_dtype(points, normals)
        p = _points(points, "points", dtype)
        n = None if normals is None else _points(normals, "normals", dtype)
        if n is not None and n.count != p.count:
            raise ValueError(f"normals has {n.count} rows for {p.count} points")
        handle = ctypes.c_void_p(None)
        prepare = _lib.sie_context_prepare_target if dtype == np.float32 else _lib.sie_context_prepare_target_d
        self._check(prepare(self._handle, p.pointer, p.count, p.stride, None if n is None else n.pointer,
                            0 if n is None else n.stride, ctypes.byref(handle)))
        return handle

    def align(self, source: CloudLike, target: Union[CloudLike, Target], init: Optional[npt.ArrayLike] = None,
              target_normals: Optional[npt.ArrayLike] = None) -> Registration:
        """ICP of source onto target; see the module docstring for the clouds accepted.
        target_normals (N x 3, unit or 0 0 0 for none) replaces the estimated normals of
        point-to-plane (float32 entry point); an Open3D target's own normals are used the same
        way unless target_normals is given. target may be a Target (prepared once; its normals
        are fixed then)."""
        opened = _open3d_cloud(source)
        if opened is not None:
            source = opened[0]
        if isinstance(target, Target):
            if target_normals is not None:
                raise ValueError("a Target carries its normals: pass them to prepare_target instead")
            if not target._handle.value:
                raise SieError(Status.NULL_ARGUMENT, "the target is closed")
            dtype = _cloud_dtype(source)
            s = _points(source, "source", dtype)
            transform_in = _transform_in(init)
            out = np.empty((4, 4), dtype=np.float64)
            register_to = _lib.sie_context_register_to if dtype == np.float32 else _lib.sie_context_register_to_d
            self._run(register_to(self._handle, s.pointer, s.count, s.stride, target._handle,
                                  _double_pointer(transform_in), _double_pointer(out)))
            return self._registration(out)
        opened = _open3d_cloud(target)
        if opened is not None:
            target = opened[0]
            if target_normals is None:
                target_normals = opened[1]
        transform_in = _transform_in(init)
        out = np.empty((4, 4), dtype=np.float64)
        if target_normals is not None:
            s = _points(source, "source", np.float32)
            t = _points(target, "target", np.float32)
            n = _points(target_normals, "target_normals", np.float32)
            if n.count != t.count:
                raise ValueError(f"target_normals has {n.count} rows for {t.count} target points")
            status = _lib.sie_context_register_with_normals(
                self._handle, s.pointer, s.count, s.stride, t.pointer, t.count, t.stride, n.pointer, n.stride,
                _double_pointer(transform_in), _double_pointer(out),
            )
        else:
            dtype = _cloud_dtype(source, target)
            s = _points(source, "source", dtype)
            t = _points(target, "target", dtype)
            register = _lib.sie_context_register if dtype == np.float32 else _lib.sie_context_register_d
            status = register(
                self._handle, s.pointer, s.count, s.stride, t.pointer, t.count, t.stride,
                _double_pointer(transform_in), _double_pointer(out),
            )
        self._run(status)
        return self._registration(out)

    def align_correspondences(self, source: npt.ArrayLike, target: npt.ArrayLike,
                              init: Optional[npt.ArrayLike] = None) -> Registration:
        """Matched pairs: source[i] corresponds to target[i]; always point-to-point."""
        dtype = _cloud_dtype(source, target)
        s = _points(source, "source", dtype)
        t = _points(target, "target", dtype)
        if s.count != t.count:
            raise ValueError(f"source has {s.count} points and target {t.count}; pairs need equal counts")
        transform_in = _transform_in(init)
        out = np.empty((4, 4), dtype=np.float64)
        register = (
            _lib.sie_context_register_correspondences
            if dtype == np.float32
            else _lib.sie_context_register_correspondences_d
        )
        status = register(
            self._handle, s.pointer, s.stride, t.pointer, t.stride, s.count, _double_pointer(transform_in),
            _double_pointer(out),
        )
        self._run(status)
        return self._registration(out)

    def _registration(self, transform: np.ndarray) -> Registration:
        return Registration(transform, self.summary(), self.inlier_probabilities(), self.correspondences())

    # ---- results of the last successful registration -----------------------------------

    def summary(self) -> Summary:
        raw = _native.sie_summary()
        self._check(_lib.sie_context_get_summary(self._handle, ctypes.byref(raw)))
        return Summary(
            tuple(raw.sigma), tuple(raw.beta), raw.penalty, raw.noise_shape, raw.inlier_fraction, raw.rmse,
            raw.init_correction, int(raw.source_count), int(raw.correspondence_count), int(raw.iterations),
            _enum_or_int(StopReason, raw.stop_reason), int(raw.histogram_count), bool(raw.converged),
            _enum_or_int(Verdict, raw.verdict), raw.significance, raw.conditioning, raw.sigma_to_spacing,
            raw.margin, _enum_or_int(StartKind, raw.start), int(raw.starts_run), int(raw.agreeing_starts),
            int(raw.hypotheses), raw.runner_up_significance,
        )

    def _array(self, getter: Any, dtype: npt.DTypeLike, ctype: Any) -> np.ndarray:
        length = ctypes.c_size_t(0)
        self._check(getter(self._handle, None, 0, ctypes.byref(length)))
        values = np.empty(length.value, dtype=dtype)
        self._check(getter(self._handle, values.ctypes.data_as(ctypes.POINTER(ctype)), values.size,
                           ctypes.byref(length)))
        return values[: length.value]

    def inlier_probabilities(self) -> np.ndarray:
        return self._array(_lib.sie_context_get_inlier_probabilities, np.float64, ctypes.c_double)

    def correspondences(self) -> np.ndarray:
        return self._array(_lib.sie_context_get_correspondences, np.int64, ctypes.c_int64)

    def trace(self) -> List[TraceEntry]:
        length = ctypes.c_size_t(0)
        self._check(_lib.sie_context_get_trace(self._handle, None, 0, ctypes.byref(length)))
        entries = (_native.sie_trace_entry * length.value)()
        self._check(_lib.sie_context_get_trace(self._handle, entries, length.value, ctypes.byref(length)))
        return [_trace_entry(e) for e in entries[: length.value]]

    def histogram(self, index: int = 0) -> Histogram:
        model = _native.sie_model()
        self._check(_lib.sie_context_get_histogram(self._handle, index, ctypes.byref(model), None, None, None,
                                                   None, 0))
        arrays = [np.empty(int(model.bins), dtype=np.float64) for _ in range(4)]
        pointers = [_double_pointer(a) for a in arrays]
        self._check(_lib.sie_context_get_histogram(self._handle, index, ctypes.byref(model), *pointers,
                                                   int(model.bins)))
        return Histogram(_model(model), *arrays)

    # ---- the estimator alone -----------------------------------------------------------

    def estimate_inliers(self, residuals: npt.ArrayLike, row_scales: Optional[npt.ArrayLike] = None,
                         beta: float = 0.0) -> InlierEstimate:
        """P(inlier) per row of a residual matrix (rows x cols, or a 1-D vector of rows x 1).
        At least 10 rows (SieError TOO_FEW_POINTS otherwise: too few to fit a histogram)."""
        matrix = np.ascontiguousarray(_real_array(residuals, "residuals"), dtype=np.float64)
        if matrix.ndim == 1:
            matrix = matrix.reshape(-1, 1)
        if matrix.ndim != 2:
            raise ValueError(f"residuals must be 1-D or 2-D, got shape {matrix.shape}")
        rows, cols = matrix.shape
        scales = None
        if row_scales is not None:
            scales = np.ascontiguousarray(_real_array(row_scales, "row_scales"), dtype=np.float64)
            if scales.shape != (rows,):
                raise ValueError(f"row_scales must have shape ({rows},), got {scales.shape}")
        probabilities = np.empty(rows, dtype=np.float64)
        models = (_native.sie_model * max(cols, 1))()
        count = ctypes.c_size_t(0)
        self._check(_lib.sie_estimate_inliers(
            self._handle, _double_pointer(matrix), rows, cols, _double_pointer(scales), float(beta),
            _double_pointer(probabilities), models, len(models), ctypes.byref(count),
        ))
        return InlierEstimate(probabilities, [_model(m) for m in models[: count.value]])


def align(source: CloudLike, target: CloudLike, init: Optional[npt.ArrayLike] = None,
          target_normals: Optional[npt.ArrayLike] = None, **settings: Any) -> Registration:
    """One registration with a fresh Context: sie.align(source, target, max_iterations=100, ...)
    is Context(**settings).align(source, target, init, target_normals). Clouds are N x 3 arrays
    or Open3D point clouds (an Open3D target's normals are used for point-to-plane)."""
    with Context(**settings) as context:
        return context.align(source, target, init=init, target_normals=target_normals)
