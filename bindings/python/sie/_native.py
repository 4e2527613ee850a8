"""Loading libsie and declaring its C functions (mirrors include/sie.h; no compiled Python code).

The library is a plain shared library called through ctypes.CDLL, which releases the GIL for
the duration of every call: registrations in several Python threads run in parallel."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from pathlib import Path
from typing import Iterator

# The ABI this module is written against: sie.h 0.2 (soname libsie.so.0.2).
ABI_MAJOR = 0
ABI_MINOR = 2
SONAME = f"libsie.so.{ABI_MAJOR}.{ABI_MINOR}" if ABI_MAJOR == 0 else f"libsie.so.{ABI_MAJOR}"

c_double_p = ctypes.POINTER(ctypes.c_double)
c_float_p = ctypes.POINTER(ctypes.c_float)
c_size_t_p = ctypes.POINTER(ctypes.c_size_t)
status_t = ctypes.c_uint32


class sie_summary(ctypes.Structure):
    _fields_ = [
        ("sigma", ctypes.c_double * 3),
        ("beta", ctypes.c_double * 3),
        ("penalty", ctypes.c_double),
        ("noise_shape", ctypes.c_double),
        ("inlier_fraction", ctypes.c_double),
        ("rmse", ctypes.c_double),
        ("init_correction", ctypes.c_double),
        ("source_count", ctypes.c_uint64),
        ("correspondence_count", ctypes.c_uint64),
        ("iterations", ctypes.c_uint32),
        ("stop_reason", ctypes.c_uint32),
        ("histogram_count", ctypes.c_uint32),
        ("converged", ctypes.c_bool),
        ("verdict", ctypes.c_uint32),
        ("start", ctypes.c_uint32),
        ("significance", ctypes.c_double),
        ("conditioning", ctypes.c_double),
        ("sigma_to_spacing", ctypes.c_double),
        ("margin", ctypes.c_double),
        ("runner_up_significance", ctypes.c_double),
        ("starts_run", ctypes.c_uint32),
        ("hypotheses", ctypes.c_uint32),
        ("agreeing_starts", ctypes.c_uint32),
    ]


class sie_model(ctypes.Structure):
    _fields_ = [
        ("mu", ctypes.c_double),
        ("sigma", ctypes.c_double),
        ("alpha", ctypes.c_double),
        ("noise_shape", ctypes.c_double),
        ("beta", ctypes.c_double),
        ("penalty", ctypes.c_double),
        ("range_lo", ctypes.c_double),
        ("range_hi", ctypes.c_double),
        ("mean_inlier_probability", ctypes.c_double),
        ("bins", ctypes.c_uint64),
        ("samples_in_range", ctypes.c_uint64),
        ("peak_found", ctypes.c_bool),
    ]


class sie_trace_entry(ctypes.Structure):
    _fields_ = [
        ("sigma", ctypes.c_double),
        ("beta", ctypes.c_double),
        ("penalty", ctypes.c_double),
        ("inlier_fraction", ctypes.c_double),
        ("rmse", ctypes.c_double),
        ("translation_change", ctypes.c_double),
        ("rotation_change", ctypes.c_double),
        ("correspondences", ctypes.c_uint64),
        ("iteration", ctypes.c_uint32),
        ("annealing", ctypes.c_bool),
        ("transform", ctypes.c_double * 16),
    ]


# int32_t (*sie_noise_fn)(void *user_data, uint32_t cloud, const double *xyz, size_t n, double *out_sigma)
NOISE_FN = ctypes.CFUNCTYPE(
    ctypes.c_int32, ctypes.c_void_p, ctypes.c_uint32, c_double_p, ctypes.c_size_t, c_double_p
)

# int32_t (*sie_progress_fn)(void *user_data, const sie_trace_entry *entry)
PROGRESS_FN = ctypes.CFUNCTYPE(ctypes.c_int32, ctypes.c_void_p, ctypes.POINTER(sie_trace_entry))

_ctx = ctypes.c_void_p
_target = ctypes.c_void_p
_odometry = ctypes.c_void_p

# name: (restype, argtypes)
_SIGNATURES = {
    "sie_version_string": (ctypes.c_char_p, []),
    "sie_version_number": (ctypes.c_uint32, []),
    "sie_status_str": (ctypes.c_char_p, [ctypes.c_uint32]),
    "sie_context_new": (_ctx, []),
    "sie_context_free": (None, [_ctx]),
    "sie_context_cancel": (status_t, [_ctx]),
    "sie_context_last_error": (ctypes.c_char_p, [_ctx]),
    "sie_context_set_cost_function": (status_t, [_ctx, ctypes.c_uint32, ctypes.c_double]),
    "sie_context_set_metric": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_starts": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_warm_start": (status_t, [_ctx, ctypes.POINTER(sie_summary)]),
    "sie_context_set_max_iterations": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_convergence": (status_t, [_ctx, ctypes.c_double, ctypes.c_double]),
    "sie_context_set_noise_model": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_noise_callback": (status_t, [_ctx, NOISE_FN, ctypes.c_void_p]),
    "sie_context_set_noise_shape": (status_t, [_ctx, ctypes.c_double]),
    "sie_context_set_histogram_mode": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_regularizer": (status_t, [_ctx, ctypes.c_double, ctypes.c_double]),
    "sie_context_set_max_correspondences": (status_t, [_ctx, ctypes.c_size_t]),
    "sie_context_set_normal_neighbours": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_threads": (status_t, [_ctx, ctypes.c_uint32]),
    "sie_context_set_seed": (status_t, [_ctx, ctypes.c_uint64]),
    "sie_context_set_trace": (status_t, [_ctx, ctypes.c_bool]),
    "sie_context_set_skip_non_finite": (status_t, [_ctx, ctypes.c_bool]),
    "sie_context_set_skip_origin": (status_t, [_ctx, ctypes.c_bool]),
    "sie_context_set_progress_callback": (status_t, [_ctx, PROGRESS_FN, ctypes.c_void_p]),
    "sie_context_register": (
        status_t,
        [_ctx, c_float_p, ctypes.c_size_t, ctypes.c_size_t, c_float_p, ctypes.c_size_t, ctypes.c_size_t,
         c_double_p, c_double_p],
    ),
    "sie_context_register_d": (
        status_t,
        [_ctx, c_double_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, ctypes.c_size_t, ctypes.c_size_t,
         c_double_p, c_double_p],
    ),
    "sie_context_register_with_normals": (
        status_t,
        [_ctx, c_float_p, ctypes.c_size_t, ctypes.c_size_t, c_float_p, ctypes.c_size_t, ctypes.c_size_t,
         c_float_p, ctypes.c_size_t, c_double_p, c_double_p],
    ),
    "sie_context_register_correspondences": (
        status_t,
        [_ctx, c_float_p, ctypes.c_size_t, c_float_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, c_double_p],
    ),
    "sie_context_register_correspondences_d": (
        status_t,
        [_ctx, c_double_p, ctypes.c_size_t, c_double_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, c_double_p],
    ),
    "sie_context_prepare_target": (
        status_t,
        [_ctx, c_float_p, ctypes.c_size_t, ctypes.c_size_t, c_float_p, ctypes.c_size_t, ctypes.POINTER(_target)],
    ),
    "sie_context_prepare_target_d": (
        status_t,
        [_ctx, c_double_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, ctypes.c_size_t, ctypes.POINTER(_target)],
    ),
    "sie_target_estimate_normals": (status_t, [_target, ctypes.c_uint32]),
    "sie_target_point_count": (ctypes.c_size_t, [_target]),
    "sie_target_free": (None, [_target]),
    "sie_context_register_to": (
        status_t,
        [_ctx, c_float_p, ctypes.c_size_t, ctypes.c_size_t, _target, c_double_p, c_double_p],
    ),
    "sie_context_register_to_d": (
        status_t,
        [_ctx, c_double_p, ctypes.c_size_t, ctypes.c_size_t, _target, c_double_p, c_double_p],
    ),
    "sie_context_odometry_new": (status_t, [_ctx, ctypes.POINTER(_odometry)]),
    "sie_context_odometry_register_frame": (
        status_t,
        [_ctx, _odometry, c_float_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, ctypes.POINTER(ctypes.c_uint32)],
    ),
    "sie_context_odometry_register_frame_d": (
        status_t,
        [_ctx, _odometry, c_double_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, ctypes.POINTER(ctypes.c_uint32)],
    ),
    "sie_odometry_skip_frame": (None, [_odometry]),
    "sie_odometry_pose": (status_t, [_odometry, c_double_p]),
    "sie_odometry_free": (None, [_odometry]),
    "sie_context_get_summary": (status_t, [_ctx, ctypes.POINTER(sie_summary)]),
    "sie_context_get_inlier_probabilities": (status_t, [_ctx, c_double_p, ctypes.c_size_t, c_size_t_p]),
    "sie_context_get_correspondences": (
        status_t,
        [_ctx, ctypes.POINTER(ctypes.c_int64), ctypes.c_size_t, c_size_t_p],
    ),
    "sie_context_get_histogram": (
        status_t,
        [_ctx, ctypes.c_size_t, ctypes.POINTER(sie_model), c_double_p, c_double_p, c_double_p, c_double_p,
         ctypes.c_size_t],
    ),
    "sie_context_get_trace": (
        status_t,
        [_ctx, ctypes.POINTER(sie_trace_entry), ctypes.c_size_t, c_size_t_p],
    ),
    "sie_context_get_pose_uncertainty": (status_t, [_ctx, c_double_p, c_double_p]),
    "sie_estimate_inliers": (
        status_t,
        [_ctx, c_double_p, ctypes.c_size_t, ctypes.c_size_t, c_double_p, ctypes.c_double, c_double_p,
         ctypes.POINTER(sie_model), ctypes.c_size_t, c_size_t_p],
    ),
}


BUNDLED = Path(__file__).resolve().parent / SONAME


def _candidates() -> Iterator[str]:
    """Where to look for the library, in order (see the package README)."""
    explicit = os.environ.get("SIE_LIBRARY")
    if explicit:
        # An explicit choice is final: silently loading another copy would hide a mistake.
        yield explicit
        return
    # The copy pip installed inside the package (setup.py builds it with cargo).
    if BUNDLED.exists():
        yield str(BUNDLED)
    yield SONAME  # the dynamic loader's own search: LD_LIBRARY_PATH, ldconfig cache, /usr/lib
    for prefix in dict.fromkeys([sys.prefix, "/usr/local", "/usr"]):
        for libdir in ("lib", "lib64", "lib/x86_64-linux-gnu", "lib/aarch64-linux-gnu"):
            path = Path(prefix, libdir, SONAME)
            if path.exists():
                yield str(path)
    found = ctypes.util.find_library("sie")
    if found:
        yield found


def load_library() -> ctypes.CDLL:
    errors = []
    for candidate in _candidates():
        try:
            library = ctypes.CDLL(candidate)
        except OSError as error:
            errors.append(f"{candidate}: {error}")
            continue
        for name, (restype, argtypes) in _SIGNATURES.items():
            function = getattr(library, name)
            function.restype = restype
            function.argtypes = argtypes
        number = library.sie_version_number()
        if (number >> 16, (number >> 8) & 0xFF) != (ABI_MAJOR, ABI_MINOR):
            raise ImportError(
                f"{candidate} is libsie {library.sie_version_string().decode()}, this binding needs "
                f"{ABI_MAJOR}.{ABI_MINOR}.x"
            )
        return library
    raise ImportError(
        "libsie not found: `pip install ./bindings/python` builds it into the package (needs the Rust "
        "toolchain), a wheel carries it; or set SIE_LIBRARY to the path of " + SONAME + ". Tried: "
        + "; ".join(errors or ["nothing"])
    )
