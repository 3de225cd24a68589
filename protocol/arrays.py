"""Array maps of the wire format: ``{"dtype", "shape", "data"}``, C order, little endian."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from protocol.errors import DecodeError, ShapeError

#: The dtypes PROTOCOL.md allows on the wire.
WIRE_DTYPES = frozenset({"<f4", "<f8", "<c8", "<i4", "<u2"})


def encode_array(a: npt.ArrayLike, dtype: str) -> dict[str, Any]:
    """Encode ``a`` as a wire array map of the given wire ``dtype`` (one of :data:`WIRE_DTYPES`).

    The data are converted to ``dtype`` and laid out C-contiguous, little endian.
    """
    if dtype not in WIRE_DTYPES:
        raise ShapeError(f"dtype {dtype!r} is not a wire dtype")
    arr = np.ascontiguousarray(a, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": list(arr.shape), "data": arr.tobytes()}


def decode_array(
    obj: Any,
    field: str,
    *,
    dtypes: frozenset[str] = WIRE_DTYPES,
    ndim: int | None = None,
    finite: bool = True,
) -> npt.NDArray[Any]:
    """Decode and validate a wire array map.

    Parameters
    ----------
    obj : the decoded msgpack value of the field.
    field : the field name, for the error message.
    dtypes : the dtypes this field accepts.
    ndim : the required number of dimensions, or None for any.
    finite : reject NaN and Inf (for float and complex dtypes).

    Returns
    -------
    ndarray, read-only view on the payload bytes, in native byte order when it is little endian.
    """
    if not isinstance(obj, Mapping):
        raise DecodeError(f"field {field!r}: expected an array map, got {type(obj).__name__}")
    dtype, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("data")
    if not isinstance(dtype, str) or dtype not in WIRE_DTYPES:
        raise ShapeError(f"field {field!r}: unknown dtype {dtype!r}")
    if dtype not in dtypes:
        raise ShapeError(f"field {field!r}: dtype {dtype} not allowed here ({sorted(dtypes)})")
    if not isinstance(shape, list | tuple) or not all(
        isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape
    ):
        raise ShapeError(f"field {field!r}: shape must be a list of non-negative ints")
    if ndim is not None and len(shape) != ndim:
        raise ShapeError(f"field {field!r}: expected {ndim} dimensions, got shape {list(shape)}")
    if not isinstance(data, bytes | bytearray | memoryview):
        raise DecodeError(f"field {field!r}: data must be binary")
    dt = np.dtype(dtype)
    # Python ints: np.prod in int64 wraps (or overflows) on huge shapes.
    expected = math.prod(shape) * dt.itemsize
    if len(data) != expected:
        raise ShapeError(
            f"field {field!r}: data has {len(data)} bytes, shape {list(shape)} x {dtype} "
            f"needs {expected}"
        )
    arr = np.frombuffer(data, dtype=dt).reshape(shape)
    if finite and dt.kind in "fc" and arr.size and not np.isfinite(arr).all():
        raise ShapeError(f"field {field!r}: contains NaN or Inf")
    return arr
