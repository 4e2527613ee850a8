"""Clouds, transforms and residuals as the library reads them: numpy input checks, zero-copy
views where the layout allows, Open3D clouds."""

from __future__ import annotations

import ctypes
from typing import Any, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import _native


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


#: A cloud: an N x 3 (or N x 4) array-like of real numbers, or an Open3D point cloud.
CloudLike = Union[npt.ArrayLike, Any]
