"""Odometry: a sensor's frames registered one after another (sie_odometry)."""

from __future__ import annotations

import ctypes
from typing import Any, NamedTuple, Optional

import numpy as np

from ._arrays import CloudLike, _cloud_dtype, _double_pointer, _open3d_cloud, _points
from ._context import Context
from ._enums import FrameStatus, Status, _enum_or_int
from ._handle import _Handle
from ._library import SieError, _lib
from ._results import Summary


class Frame(NamedTuple):
    """One frame's outcome. pose: T_world_sensor (4 x 4) for FIRST, ACCEPTED and LOOSE, else
    None. summary: the frame's registration onto the last accepted frame (ACCEPTED, LOOSE,
    NOT_GOOD, JUMPED), else None."""

    status: FrameStatus
    pose: Optional[np.ndarray]
    summary: Optional[Summary]


class Odometry:
    """Frame-to-frame odometry: each frame registers onto the last accepted frame from a
    constant-velocity guess, and only a GOOD registration (or a LOOSE one: GOOD but for its
    conditioning) moves the trajectory. A frame the
    library refuses as input (too few points, NaN where not skipped) raises SieError and changes
    nothing; the odometry goes on as if it had not come.

    Odometry(**settings) takes Context settings; sensor frames' missing returns (NaN, 0 0 0)
    are skipped unless skip_non_finite / skip_origin say otherwise. Freed by close() or the
    garbage collector. One call at a time."""

    def __init__(self, **settings: Any) -> None:
        settings = {"skip_non_finite": True, "skip_origin": True, **settings}
        self._context = Context(**settings)
        handle = ctypes.c_void_p(None)
        self._context._call(_lib.sie_context_odometry_new, ctypes.byref(handle))
        self._h = _Handle(handle, _lib.sie_odometry_free, "odometry")

    def register_frame(self, points: CloudLike) -> Frame:
        """Registers the next frame (N x 3 points in the sensor's frame, or an Open3D cloud)."""
        opened = _open3d_cloud(points)
        if opened is not None:
            points = opened[0]
        dtype = _cloud_dtype(points)
        p = _points(points, "points", dtype)
        pose = np.empty((4, 4), dtype=np.float64)
        status = ctypes.c_uint32(int(FrameStatus.NOT_GOOD))
        register = (_lib.sie_context_odometry_register_frame if dtype == np.float32
                    else _lib.sie_context_odometry_register_frame_d)
        with self._context._h.use() as context, self._h.use() as odometry:
            result = register(context, odometry, p.pointer, p.count, p.stride, _double_pointer(pose),
                              ctypes.byref(status))
            self._context._run(context, result)
            frame_status = _enum_or_int(FrameStatus, status.value)
            registered = result == Status.OK and frame_status in (
                FrameStatus.ACCEPTED, FrameStatus.LOOSE, FrameStatus.NOT_GOOD, FrameStatus.JUMPED)
            summary = self._context._summary(context) if registered or result == Status.CANCELLED else None
        has_pose = result == Status.OK and frame_status in (
            FrameStatus.FIRST, FrameStatus.ACCEPTED, FrameStatus.LOOSE)
        return Frame(frame_status, pose if has_pose else None, summary)

    @property
    def pose(self) -> np.ndarray:
        """T_world_sensor of the last accepted frame (the identity before the first)."""
        out = np.empty((4, 4), dtype=np.float64)
        with self._h.use() as odometry:
            status = _lib.sie_odometry_pose(odometry, _double_pointer(out))
        if status != Status.OK:
            raise SieError(status, "sie_odometry_pose failed")
        return out

    def skip_frame(self) -> None:
        """A frame the driver dropped: the next frame's guess moves one frame further."""
        with self._h.use() as odometry:
            _lib.sie_odometry_skip_frame(odometry)

    def close(self) -> None:
        """Frees the odometry and its context. Idempotent."""
        for name in ("_h", "_context"):
            handle = getattr(self, name, None)
            if handle is not None:
                handle.close()

    def __enter__(self) -> "Odometry":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()
