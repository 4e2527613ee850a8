"""Context (settings, callbacks, registrations, results), Target and align()."""

from __future__ import annotations

import ctypes
from typing import Any, Callable, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import _native
from ._arrays import CloudLike, _cloud_dtype, _double_pointer, _open3d_cloud, _points, _real_array, _transform_in
from ._enums import Cloud, CostFunction, HistogramMode, Metric, NoiseModel, Starts, Status, _enum_arg, _enum_or_int
from ._enums import StartKind, StopReason, Verdict
from ._handle import _Handle
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
        with Context(normal_neighbours=normal_neighbours, skip_non_finite=skip_non_finite) as context:
            self._h = _Handle(context._prepare(points, normals), _lib.sie_target_free, "target")

    @classmethod
    def _adopt(cls, handle: ctypes.c_void_p) -> "Target":
        target = cls.__new__(cls)
        target._h = _Handle(handle, _lib.sie_target_free, "target")
        return target

    def __len__(self) -> int:
        """Points the target was made from (0 once closed)."""
        try:
            with self._h.use() as handle:
                return int(_lib.sie_target_point_count(handle))
        except SieError:
            return 0

    def estimate_normals(self, threads: int = 0) -> None:
        """Estimates every normal not estimated yet (threads: 0 = one per core), so that no later
        align() pays for them. Results are the same either way."""
        with self._h.use() as handle:
            status = _lib.sie_target_estimate_normals(handle, int(threads))
        if status != Status.OK:
            raise SieError(status, f"threads = {threads}; at most 1024")

    def close(self) -> None:
        """Frees the target. Never waits and never fails: while an align() onto it or
        estimate_normals() runs (close() called from a progress or noise callback, or from
        another thread), the target is freed when the last of them returns. Further uses raise
        SieError (NULL_ARGUMENT, "the target is closed"). Idempotent."""
        handle = getattr(self, "_h", None)
        if handle is not None:
            handle.close()

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
    (CostFunction, parameter). Wherever an enum is taken (cost, metric, starts, noise_model,
    histogram_mode) its name works too, in any case and with - for _ as the CLI spells it:
    Context(metric="point_to_point", cost=("huber", 0.1)); an unknown name is a ValueError
    that lists the valid ones."""

    def __init__(self, **settings: Any) -> None:
        handle = _lib.sie_context_new()
        if not handle:
            raise MemoryError("sie_context_new returned NULL")
        self._h = _Handle(handle, _lib.sie_context_free, "context")
        # What a callback raised, re-raised by align*().
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
        """Frees the context (also done by the garbage collector). Never waits and never fails:
        called while an align*() or another call on this context runs (from its progress or
        noise callback, or from another thread), it only marks the context closed, and the
        running call finishes normally (align*() returns its result) and then frees it; call
        cancel() first to stop that call sooner. Every later call raises SieError
        (NULL_ARGUMENT, "the context is closed"). Idempotent."""
        handle = getattr(self, "_h", None)
        if handle is not None:
            handle.close()

    def cancel(self) -> None:
        """Asks the running registration to stop after its current iteration (or, if none runs,
        the next one after its first). May be called from any thread while align*() runs, also
        after a close() that waits for that align*()."""
        handle = getattr(self, "_h", None)
        if handle is not None:
            handle.cancel(_lib.sie_context_cancel)

    def __enter__(self) -> "Context":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

    # ---- errors ------------------------------------------------------------------------

    @staticmethod
    def _check(handle: ctypes.c_void_p, status: int) -> None:
        if status != Status.OK:
            raise SieError(status, _lib.sie_context_last_error(handle).decode(errors="replace"))

    def _call(self, function: Any, *args: Any) -> None:
        """function(context, *args) on the open context; a failure raises SieError."""
        with self._h.use() as handle:
            self._check(handle, function(handle, *args))

    def _run(self, handle: ctypes.c_void_p, status: int) -> None:
        """_check for registrations: re-raises what a callback raised (it made the library return
        CALLBACK_FAILED or CANCELLED); a plain cancellation is a result, not an error."""
        error, self._callback_error = self._callback_error, None
        if error is not None and status in (Status.CALLBACK_FAILED, Status.CANCELLED):
            raise error
        if status != Status.CANCELLED:
            self._check(handle, status)

    # ---- settings ----------------------------------------------------------------------

    def set_cost_function(self, cost: Union[CostFunction, str, int], parameter: float = 0.0) -> "Context":
        self._call(_lib.sie_context_set_cost_function, _enum_arg(CostFunction, cost, "cost"), float(parameter))
        return self

    def set_metric(self, metric: Union[Metric, str, int]) -> "Context":
        self._call(_lib.sie_context_set_metric, _enum_arg(Metric, metric, "metric"))
        return self

    def set_starts(self, starts: Union[Starts, str, int]) -> "Context":
        """Starts.AUTOMATIC (the default) runs SIE from several starts and keeps the most
        significant result; Starts.INITIAL_GUESS runs from the initial guess, and once more
        from its result when it ended more than 10 fitted sigma away beyond a local correction
        (half the target's spread, every direction fixed; the more significant of the two is
        kept), and when that far result is not GOOD with a narrow beta from the guess too."""
        self._call(_lib.sie_context_set_starts, _enum_arg(Starts, starts, "starts"))
        return self

    def set_warm_start(self, previous: Optional[Summary]) -> "Context":
        """Starts the following registrations from the noise model of `previous`, an earlier SIE
        registration's Summary (None: start cold again). For sequences registered from good
        guesses; falls back to the full search by itself when the guess was bad
        (Summary.start is StartKind.WARM_START when the warm run was kept). A Summary whose
        verdict is DOUBTFUL or UNSUPPORTED clears it: the frame after such a one rarely keeps
        its warm run (the same loose scene or bad guess again), which would be paid for and
        dropped."""
        if previous is None:
            self._call(_lib.sie_context_set_warm_start, None)
            return self
        raw = _native.sie_summary()
        raw.sigma[:] = list(previous.sigma)
        raw.beta[:] = list(previous.beta)
        raw.penalty = previous.penalty
        raw.noise_shape = previous.noise_shape
        raw.inlier_fraction = previous.inlier_fraction
        raw.histogram_count = previous.histogram_count
        raw.verdict = int(previous.verdict)
        self._call(_lib.sie_context_set_warm_start, ctypes.byref(raw))
        return self

    def set_max_iterations(self, max_iterations: int) -> "Context":
        """Caps the updates of each start (Summary.iterations counts those of all starts)."""
        self._call(_lib.sie_context_set_max_iterations, int(max_iterations))
        return self

    def set_convergence(self, translation: float, rotation_radians: float) -> "Context":
        self._call(_lib.sie_context_set_convergence, float(translation), float(rotation_radians))
        return self

    def set_noise_model(self, model: Union[NoiseModel, str, int]) -> "Context":
        self._call(_lib.sie_context_set_noise_model, _enum_arg(NoiseModel, model, "noise_model"))
        return self

    def set_noise_shape(self, p: float) -> "Context":
        self._call(_lib.sie_context_set_noise_shape, float(p))
        return self

    def set_histogram_mode(self, mode: Union[HistogramMode, str, int]) -> "Context":
        self._call(_lib.sie_context_set_histogram_mode, _enum_arg(HistogramMode, mode, "histogram_mode"))
        return self

    def set_regularizer(self, initial_beta: float, shrink: float) -> "Context":
        self._call(_lib.sie_context_set_regularizer, float(initial_beta), float(shrink))
        return self

    def set_max_correspondences(self, max_correspondences: int) -> "Context":
        self._call(_lib.sie_context_set_max_correspondences, int(max_correspondences))
        return self

    def set_normal_neighbours(self, neighbours: int) -> "Context":
        self._call(_lib.sie_context_set_normal_neighbours, int(neighbours))
        return self

    def set_threads(self, threads: int) -> "Context":
        self._call(_lib.sie_context_set_threads, int(threads))
        return self

    def set_seed(self, seed: int) -> "Context":
        self._call(_lib.sie_context_set_seed, int(seed))
        return self

    def set_trace(self, enabled: bool) -> "Context":
        self._call(_lib.sie_context_set_trace, bool(enabled))
        return self

    def set_skip_non_finite(self, enabled: bool) -> "Context":
        """Drop points with NaN/inf coordinates instead of failing; they get probability 0 and
        correspondence -1."""
        self._call(_lib.sie_context_set_skip_non_finite, bool(enabled))
        return self

    def set_skip_origin(self, enabled: bool) -> "Context":
        """Drop points at exactly 0 0 0 (depth sensors' invalid pixels) like non-finite ones."""
        self._call(_lib.sie_context_set_skip_origin, bool(enabled))
        return self

    def _set_callback(self, name: str, setter: Any, callback: Any) -> None:
        with self._h.use() as handle:
            self._check(handle, setter(handle, callback, None))
            # The library points at it now: kept alive until the context is freed or it is replaced.
            self._h.keep[name] = callback

    def set_progress_callback(self, function: Optional[ProgressCallback]) -> "Context":
        """function(entry: TraceEntry) after every iteration, on the calling thread; returning
        False cancels the registration (None or True continue). Whatever it raises cancels it and
        is re-raised by align*(). None removes it. It may call close() (see there)."""
        if function is None:
            self._set_callback("progress", _lib.sie_context_set_progress_callback, _native.PROGRESS_FN())
            return self

        def trampoline(_user_data: Any, entry: Any) -> int:
            try:
                return 1 if function(_trace_entry(entry.contents)) is False else 0
            except BaseException as error:  # noqa: BLE001 - re-raised by _run after the call
                self._callback_error = error
                return 1

        self._set_callback("progress", _lib.sie_context_set_progress_callback, _native.PROGRESS_FN(trampoline))
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
            self._set_callback("noise", _lib.sie_context_set_noise_callback, _native.NOISE_FN())
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

        self._set_callback("noise", _lib.sie_context_set_noise_callback, _native.NOISE_FN(trampoline))
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
        target = ctypes.c_void_p(None)
        prepare = _lib.sie_context_prepare_target if dtype == np.float32 else _lib.sie_context_prepare_target_d
        self._call(prepare, p.pointer, p.count, p.stride, None if n is None else n.pointer,
                   0 if n is None else n.stride, ctypes.byref(target))
        return target

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
            dtype = _cloud_dtype(source)
            s = _points(source, "source", dtype)
            transform_in = _transform_in(init)
            out = np.empty((4, 4), dtype=np.float64)
            register_to = _lib.sie_context_register_to if dtype == np.float32 else _lib.sie_context_register_to_d
            # Both stay allocated until the call returns, whoever closes them meanwhile.
            with self._h.use() as handle, target._h.use() as prepared:
                self._run(handle, register_to(handle, s.pointer, s.count, s.stride, prepared,
                                              _double_pointer(transform_in), _double_pointer(out)))
                return self._registration(handle, out)
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
            with self._h.use() as handle:
                status = _lib.sie_context_register_with_normals(
                    handle, s.pointer, s.count, s.stride, t.pointer, t.count, t.stride, n.pointer, n.stride,
                    _double_pointer(transform_in), _double_pointer(out),
                )
                self._run(handle, status)
                return self._registration(handle, out)
        dtype = _cloud_dtype(source, target)
        s = _points(source, "source", dtype)
        t = _points(target, "target", dtype)
        register = _lib.sie_context_register if dtype == np.float32 else _lib.sie_context_register_d
        with self._h.use() as handle:
            status = register(
                handle, s.pointer, s.count, s.stride, t.pointer, t.count, t.stride,
                _double_pointer(transform_in), _double_pointer(out),
            )
            self._run(handle, status)
            return self._registration(handle, out)

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
        with self._h.use() as handle:
            status = register(
                handle, s.pointer, s.stride, t.pointer, t.stride, s.count, _double_pointer(transform_in),
                _double_pointer(out),
            )
            self._run(handle, status)
            return self._registration(handle, out)

    def _registration(self, handle: ctypes.c_void_p, transform: np.ndarray) -> Registration:
        # Through `handle`, not the public getters: a close() from the callback refuses new calls.
        return Registration(
            transform, self._summary(handle),
            self._array(handle, _lib.sie_context_get_inlier_probabilities, np.float64, ctypes.c_double),
            self._array(handle, _lib.sie_context_get_correspondences, np.int64, ctypes.c_int64),
            *self._pose_uncertainty(handle),
        )

    # ---- results of the last successful registration -----------------------------------

    def summary(self) -> Summary:
        with self._h.use() as handle:
            return self._summary(handle)

    def _summary(self, handle: ctypes.c_void_p) -> Summary:
        raw = _native.sie_summary()
        self._check(handle, _lib.sie_context_get_summary(handle, ctypes.byref(raw)))
        return Summary(
            tuple(raw.sigma), tuple(raw.beta), raw.penalty, raw.noise_shape, raw.inlier_fraction, raw.rmse,
            raw.init_correction, int(raw.source_count), int(raw.correspondence_count), int(raw.iterations),
            _enum_or_int(StopReason, raw.stop_reason), int(raw.histogram_count), bool(raw.converged),
            _enum_or_int(Verdict, raw.verdict), raw.significance, raw.conditioning, raw.sigma_to_spacing,
            raw.margin, _enum_or_int(StartKind, raw.start), int(raw.starts_run), int(raw.agreeing_starts),
            int(raw.hypotheses), raw.runner_up_significance,
        )

    def _array(self, handle: ctypes.c_void_p, getter: Any, dtype: npt.DTypeLike, ctype: Any) -> np.ndarray:
        length = ctypes.c_size_t(0)
        self._check(handle, getter(handle, None, 0, ctypes.byref(length)))
        values = np.empty(length.value, dtype=dtype)
        self._check(handle, getter(handle, values.ctypes.data_as(ctypes.POINTER(ctype)), values.size,
                                   ctypes.byref(length)))
        return values[: length.value]

    def pose_uncertainty(self) -> Tuple[np.ndarray, np.ndarray]:
        """(covariance, information) of the last result's pose, each 6 x 6 float64: rotation
        vector first, then translation, left perturbation in the target frame (see
        Registration)."""
        with self._h.use() as handle:
            return self._pose_uncertainty(handle)

    def _pose_uncertainty(self, handle: ctypes.c_void_p) -> Tuple[np.ndarray, np.ndarray]:
        covariance = np.empty((6, 6), dtype=np.float64)  # C order: row-major, as the C API writes
        information = np.empty((6, 6), dtype=np.float64)
        self._check(handle, _lib.sie_context_get_pose_uncertainty(handle, _double_pointer(covariance),
                                                                  _double_pointer(information)))
        return covariance, information

    def inlier_probabilities(self) -> np.ndarray:
        with self._h.use() as handle:
            return self._array(handle, _lib.sie_context_get_inlier_probabilities, np.float64, ctypes.c_double)

    def correspondences(self) -> np.ndarray:
        with self._h.use() as handle:
            return self._array(handle, _lib.sie_context_get_correspondences, np.int64, ctypes.c_int64)

    def trace(self) -> List[TraceEntry]:
        length = ctypes.c_size_t(0)
        with self._h.use() as handle:
            self._check(handle, _lib.sie_context_get_trace(handle, None, 0, ctypes.byref(length)))
            entries = (_native.sie_trace_entry * length.value)()
            self._check(handle, _lib.sie_context_get_trace(handle, entries, length.value, ctypes.byref(length)))
        return [_trace_entry(e) for e in entries[: length.value]]

    def histogram(self, index: int = 0) -> Histogram:
        model = _native.sie_model()
        with self._h.use() as handle:
            self._check(handle, _lib.sie_context_get_histogram(handle, index, ctypes.byref(model), None, None,
                                                               None, None, 0))
            arrays = [np.empty(int(model.bins), dtype=np.float64) for _ in range(4)]
            pointers = [_double_pointer(a) for a in arrays]
            self._check(handle, _lib.sie_context_get_histogram(handle, index, ctypes.byref(model), *pointers,
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
        self._call(
            _lib.sie_estimate_inliers, _double_pointer(matrix), rows, cols, _double_pointer(scales), float(beta),
            _double_pointer(probabilities), models, len(models), ctypes.byref(count),
        )
        return InlierEstimate(probabilities, [_model(m) for m in models[: count.value]])


def align(source: CloudLike, target: CloudLike, init: Optional[npt.ArrayLike] = None,
          target_normals: Optional[npt.ArrayLike] = None, **settings: Any) -> Registration:
    """One registration with a fresh Context: sie.align(source, target, max_iterations=100, ...)
    is Context(**settings).align(source, target, init, target_normals). Clouds are N x 3 arrays
    or Open3D point clouds (an Open3D target's normals are used for point-to-plane)."""
    with Context(**settings) as context:
        return context.align(source, target, init=init, target_normals=target_normals)
