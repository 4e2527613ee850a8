"""Point-cloud registration with Statistical Inlier Estimation (SIE), over libsie's C ABI.

    import sie
    result = sie.align(source, target)         # N x 3 arrays or open3d PointClouds -> sie.Registration
    result.transform                           # 4 x 4, T_target_source: p_target = T @ p_source
    result.summary.verdict                     # Verdict.GOOD: use it; DOUBTFUL: check; UNSUPPORTED: reject
    result.covariance, result.information      # 6 x 6, rotation first (see sie.Registration)
    result.fitness, result.correspondence_set  # Open3D's names; T_target_source, H: small_gicp's
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
thread at a time (except cancel() and close(), callable from any thread and from its callbacks:
a close() during a call takes effect when that call returns); distinct Contexts are independent.
The library is called through ctypes.CDLL, which releases the GIL during each call: Contexts in
different threads register in parallel.
"""

from __future__ import annotations

from ._context import Context, Target, align
from ._enums import (
    Cloud, CostFunction, FrameStatus, HistogramMode, Metric, NoiseModel, Starts, StartKind, Status, StopReason,
    Verdict,
)
from ._odometry import Frame, Odometry
from ._library import SieError, _package_version, library_version
from ._results import Histogram, InlierEstimate, Model, Registration, Summary, TraceEntry

# Also reachable as before, though not in __all__: the type aliases, and the loaded library and
# the input check that the tests use.
from ._arrays import CloudLike as CloudLike, _points as _points
from ._context import NoiseCallback as NoiseCallback, ProgressCallback as ProgressCallback
from ._library import _lib as _lib
from ._results import INLIER_PROBABILITY as INLIER_PROBABILITY

__all__ = [
    "Cloud",
    "align",
    "Context",
    "CostFunction",
    "Frame",
    "FrameStatus",
    "HistogramMode",
    "Histogram",
    "InlierEstimate",
    "Metric",
    "Model",
    "NoiseModel",
    "Odometry",
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

# Defined in the private modules but named sie.X in reprs, tracebacks and pickles, as before.
for _name in __all__:
    globals()[_name].__module__ = __name__
del _name

__version__ = _package_version()
