"""Field converters: how each field of a message travels on the wire and how it is validated.

Every field of a message dataclass names a :class:`Conv` in its metadata. One generic encoder
and one generic decoder walk the dataclass fields, so each rule of PROTOCOL.md is written once.
Written by hand because the contract needs byte-exact re-encoding and typed one-line errors,
which general schema libraries (pydantic, msgspec) do not give for msgpack maps with binary
array payloads.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

from protocol.arrays import decode_array, encode_array
from protocol.errors import DecodeError

T = TypeVar("T")

#: Node and service ids (PROTOCOL.md, "Key expressions").
# \Z, not $: "$" also matches before a trailing newline, which would let "a\n" through.
ID_RE = re.compile(r"^[A-Za-z0-9_-]+\Z")


class Conv:
    """A field converter: ``encode`` a Python value to msgpack, ``decode`` and validate one."""

    def encode(self, value: Any) -> Any:
        return value

    def decode(self, value: Any, where: str) -> Any:
        raise NotImplementedError


def _type_name(value: Any) -> str:
    return type(value).__name__


class Str(Conv):
    def __init__(self, pattern: re.Pattern[str] | None = None, choices: tuple[str, ...] = ()):
        self.pattern, self.choices = pattern, choices

    def decode(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise DecodeError(f"field {where!r}: expected str, got {_type_name(value)}")
        if self.choices and value not in self.choices:
            raise DecodeError(f"field {where!r}: {value!r} is not one of {list(self.choices)}")
        if self.pattern is not None and not self.pattern.match(value):
            raise DecodeError(f"field {where!r}: {value!r} does not match {self.pattern.pattern}")
        return value


class Int(Conv):
    def __init__(self, minimum: int | None = None):
        self.minimum = minimum

    def encode(self, value: Any) -> int:
        return int(value)

    def decode(self, value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DecodeError(f"field {where!r}: expected int, got {_type_name(value)}")
        if self.minimum is not None and value < self.minimum:
            raise DecodeError(f"field {where!r}: {value} is below {self.minimum}")
        return value


class Float(Conv):
    """A float64; msgpack ints are accepted (other tools write 0 for 0.0). NaN/Inf rejected."""

    def __init__(self, finite: bool = True):
        self.finite = finite

    def encode(self, value: Any) -> float:
        return float(value)

    def decode(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DecodeError(f"field {where!r}: expected float, got {_type_name(value)}")
        value = float(value)
        if self.finite and not math.isfinite(value):
            raise DecodeError(f"field {where!r}: NaN or Inf not allowed")
        return value


class Bool(Conv):
    def decode(self, value: Any, where: str) -> bool:
        if not isinstance(value, bool):
            raise DecodeError(f"field {where!r}: expected bool, got {_type_name(value)}")
        return value


class Vec(Conv):
    """A fixed-length list of finite floats, kept as a tuple (poses, positions)."""

    def __init__(self, n: int | None):
        self.n = n

    def encode(self, value: Any) -> list[float]:
        return [float(x) for x in value]

    def decode(self, value: Any, where: str) -> tuple[float, ...]:
        if not isinstance(value, list | tuple):
            raise DecodeError(f"field {where!r}: expected a list, got {_type_name(value)}")
        if self.n is not None and len(value) != self.n:
            raise DecodeError(f"field {where!r}: expected {self.n} numbers, got {len(value)}")
        # Fast path for the usual all-float list (every detections message has a few): the
        # per-element check below builds a field name for each number.
        if all(type(x) is float for x in value) and all(map(math.isfinite, value)):
            return tuple(value)
        return tuple(Float().decode(x, f"{where}[{i}]") for i, x in enumerate(value))


class Matrix(Conv):
    """A square list-of-lists of finite floats (covariances in ``tracks`` and ``poses``)."""

    def __init__(self, n: int):
        self.n = n

    def encode(self, value: Any) -> list[list[float]]:
        return np.asarray(value, dtype=np.float64).tolist()

    def decode(self, value: Any, where: str) -> tuple[tuple[float, ...], ...]:
        rows = value
        if not isinstance(rows, list | tuple) or len(rows) != self.n:
            raise DecodeError(f"field {where!r}: expected a {self.n}x{self.n} list")
        return tuple(Vec(self.n).decode(r, f"{where}[{i}]") for i, r in enumerate(rows))


class Array(Conv):
    """A wire array map (PROTOCOL.md, "Encoding")."""

    def __init__(self, dtypes: tuple[str, ...], ndim: int | None = None, finite: bool = True):
        self.dtypes, self.ndim, self.finite = frozenset(dtypes), ndim, finite

    def encode(self, value: Any) -> dict[str, Any]:
        arr = np.asarray(value)
        dtype = arr.dtype.newbyteorder("<").str
        if dtype not in self.dtypes:
            # A float64 array in a float32 field is converted: the field's first dtype wins.
            dtype = sorted(self.dtypes)[0] if len(self.dtypes) == 1 else _closest(dtype, self)
        return encode_array(arr, dtype)

    def decode(self, value: Any, where: str) -> Any:
        return decode_array(value, where, dtypes=self.dtypes, ndim=self.ndim, finite=self.finite)


def _closest(dtype: str, conv: Array) -> str:
    kind = np.dtype(dtype).kind
    for cand in sorted(conv.dtypes):
        if np.dtype(cand).kind == kind:
            return cand
    return sorted(conv.dtypes)[0]


class ListOf(Conv):
    def __init__(self, item: Conv):
        self.item = item

    def encode(self, value: Any) -> list[Any]:
        return [self.item.encode(x) for x in value]

    def decode(self, value: Any, where: str) -> tuple[Any, ...]:
        if not isinstance(value, list | tuple):
            raise DecodeError(f"field {where!r}: expected a list, got {_type_name(value)}")
        return tuple(self.item.decode(x, f"{where}[{i}]") for i, x in enumerate(value))


class MapOf(Conv):
    """A map with string keys (optionally matching a pattern) and converted values."""

    def __init__(self, item: Conv, key_pattern: re.Pattern[str] | None = None):
        self.item, self.key_pattern = item, key_pattern

    def encode(self, value: Any) -> dict[str, Any]:
        return {k: self.item.encode(v) for k, v in value.items()}

    def decode(self, value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, Mapping):
            raise DecodeError(f"field {where!r}: expected a map, got {_type_name(value)}")
        out = {}
        for k, v in value.items():
            if not isinstance(k, str) or (self.key_pattern and not self.key_pattern.match(k)):
                raise DecodeError(f"field {where!r}: bad key {k!r}")
            out[k] = self.item.decode(v, f"{where}.{k}")
        return out


class Nested(Conv):
    """A nested record: a frozen dataclass whose fields carry converters too."""

    def __init__(self, cls: type[Any]):
        self.cls = cls

    def encode(self, value: Any) -> dict[str, Any]:
        return encode_fields(value)

    def decode(self, value: Any, where: str) -> Any:
        return decode_fields(self.cls, value, where)


def wire(conv: Conv, **kwargs: Any) -> Any:
    """Declare a dataclass field that travels on the wire with converter ``conv``."""
    return dataclasses.field(metadata={"wire": conv}, **kwargs)


def optional(conv: Conv) -> Any:
    """Declare an optional wire field: absent on the wire when it is None."""
    return dataclasses.field(default=None, metadata={"wire": conv, "optional": True})


def encode_fields(obj: Any) -> dict[str, Any]:
    """Encode the wire fields of a dataclass instance, in declaration order, then its extras."""
    out: dict[str, Any] = {}
    plan, _ = _field_plan(type(obj))
    for fname, conv, optional in plan:
        value = getattr(obj, fname)
        if value is None and optional:
            continue
        out[fname] = conv.encode(value)
    extra = getattr(obj, "extra", None)
    if extra:
        for k, v in extra.items():
            out.setdefault(k, v)
    return out


@functools.cache
def _field_plan(cls: type) -> tuple[tuple[tuple[str, Any, bool], ...], bool]:
    """(name, converter, optional) of the wire fields of ``cls``, and whether it keeps
    ``extra``: worked out once per class (``dataclasses.fields`` per message was a tenth of
    the fusion center's time per detection)."""
    fields = dataclasses.fields(cls)
    plan = tuple(
        (f.name, f.metadata["wire"], bool(f.metadata.get("optional")))
        for f in fields
        if f.metadata.get("wire") is not None
    )
    return plan, any(f.name == "extra" for f in fields)


def decode_fields(cls: type[T], m: Any, where: str = "") -> T:
    """Decode a msgpack map into ``cls``: required fields checked, unknown fields kept in extra."""
    if not isinstance(m, Mapping):
        raise DecodeError(f"field {where or 'message'!r}: expected a map, got {_type_name(m)}")
    kwargs: dict[str, Any] = {}
    plan, keeps_extra = _field_plan(cls)
    for fname, conv, optional in plan:
        name = f"{where}.{fname}" if where else fname
        if fname not in m:
            if optional:
                continue
            raise DecodeError(f"missing required field {name!r}")
        value = m[fname]
        if value is None and optional:
            continue
        kwargs[fname] = conv.decode(value, name)
    if keeps_extra:
        known = {fname for fname, _, _ in plan}
        kwargs["extra"] = {k: v for k, v in m.items() if k not in known}
    return cls(**kwargs)
