"""Context (settings, callbacks, registrations, results), Target and align()."""

from __future__ import annotations

import ctypes
from typing import Any, Callable, List, Optional, Union

import numpy as np
import numpy.typing as npt

from . import _native
from ._arrays import CloudLike, _cloud_dtype, _double_pointer, _open3d_cloud, _points, _real_array, _transform_in
from ._enums import Cloud, CostFunction, HistogramMode, Metric, NoiseModel, Starts, Status, _enum_or_int
from ._enums import StartKind, StopReason, Verdict
from ._library import SieError, _lib
from ._results import Histogram, InlierEstimate, Registration, Summary, TraceEntry, _model, _trace_entry

NoiseCallback = Callable[[Cloud, np.ndarray], npt.ArrayLike]
ProgressCallback = Callable[[TraceEntry], Optional[bool]]


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
        """ICP of source onto target; see the package docstring (help(sie)) for the clouds accepted.
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
