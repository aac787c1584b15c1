"""Network messages: pydantic models <-> msgpack, with a schema version.

Every message on the bus is a `WireMessage` subclass with a `KIND`. On the wire it is one msgpack map,
the envelope ``{"v": SCHEMA_VERSION, "k": KIND, "d": <fields>}``. `decode` treats its input as hostile:
the size is checked before unpacking, msgpack runs with bounded lengths and no extension types, and the
fields are validated by the model (finite floats, bounded strings, bounded arrays). Whatever the input,
`decode` returns a valid model or raises `DecodeError`, never anything else.

numpy arrays go through `NDArray` (or `Annotated[np.ndarray, ArraySpec(...)]` for tighter limits): on the
wire ``{"dtype": "float32", "shape": [2, 3], "data": <little-endian C-order bytes>}``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, TypeVar

import msgpack
import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import core_schema

from swarm.errors import validation_problem

SCHEMA_VERSION = 1
DEFAULT_MAX_BYTES = 1 << 20
# Bounds the element count of any msgpack array or map: the unpacker allocates for the count it reads before
# the elements arrive, at each of up to 1024 nesting levels (so at most 1024 * 16384 * 8 B = 128 MiB, mostly
# untouched, for a hostile 80 kB input). Big numeric data belongs in an NDArray. Strings and bytes are
# bounded by the input itself.
MAX_CONTAINER_LEN = 1 << 14
MAX_STR_LEN = 4096  # default bound of every str field; a field may set its own max_length

ALLOWED_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float32", "float64"}
)
_MAX_NDIM = 32
_KIND_RE = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
_ENVELOPE_KEYS = frozenset({"v", "k", "d"})


class DecodeError(Exception):
    """A received payload that is not a valid message; `reason` is short and machine-usable:
    "too_large", "not_msgpack", "bad_envelope", "version", "kind" or "invalid"."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class ArraySpec:
    """Limits of a numpy array field; use as ``Annotated[np.ndarray, ArraySpec(max_bytes=..., ...)]``."""

    max_bytes: int = 1 << 24
    dtypes: frozenset[str] = field(default=ALLOWED_DTYPES)
    ndim: int | None = None

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(
            self.validate, serialization=core_schema.plain_serializer_function_ser_schema(to_wire_array)
        )

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return {
            "type": "object",
            "properties": {
                "dtype": {"type": "string", "enum": sorted(self.dtypes)},
                "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                "data": {"type": "string", "format": "base64"},
            },
        }

    def validate(self, value: Any) -> np.ndarray:
        if isinstance(value, np.ndarray):
            self._check(value.dtype.name, value.shape, value.nbytes)
            return value
        if isinstance(value, dict) and value.keys() == {"dtype", "shape", "data"}:
            return self._from_wire(value["dtype"], value["shape"], value["data"])
        raise ValueError("expected a numpy array or {dtype, shape, data}")

    def _check(self, dtype: str, shape: tuple[int, ...], nbytes: int) -> None:
        if dtype not in self.dtypes:
            raise ValueError(f"dtype {dtype} is not allowed")
        if self.ndim is not None and len(shape) != self.ndim:
            raise ValueError(f"expected {self.ndim} dimensions, got {len(shape)}")
        if nbytes > self.max_bytes:
            raise ValueError(f"array of {nbytes} bytes exceeds {self.max_bytes}")

    def _from_wire(self, dtype: Any, shape: Any, data: Any) -> np.ndarray:
        if not isinstance(dtype, str) or dtype not in ALLOWED_DTYPES:
            raise ValueError(f"dtype {dtype!r} is not allowed")
        if not isinstance(shape, (list, tuple)) or len(shape) > _MAX_NDIM:
            raise ValueError("shape must be a list of at most 32 sizes")
        if not all(type(n) is int and n >= 0 for n in shape):
            raise ValueError("shape sizes must be non-negative integers")
        if not isinstance(data, bytes):
            raise ValueError("data must be bytes")
        wire_dtype = np.dtype(dtype).newbyteorder("<")
        expected = math.prod(shape) * wire_dtype.itemsize
        if expected != len(data):
            raise ValueError(f"shape {list(shape)} of {dtype} needs {expected} bytes, got {len(data)}")
        self._check(dtype, tuple(shape), len(data))
        if dtype == "bool" and data and max(data) > 1:
            raise ValueError("bool array bytes must be 0 or 1")
        array = np.frombuffer(data, dtype=wire_dtype).reshape(shape)
        return array if wire_dtype.isnative else array.astype(wire_dtype.newbyteorder("="))


def to_wire_array(array: np.ndarray) -> dict[str, Any]:
    little = array.dtype.newbyteorder("<")
    return {"dtype": array.dtype.name, "shape": list(array.shape), "data": array.astype(little, copy=False).tobytes()}


NDArray = Annotated[np.ndarray, ArraySpec()]


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and bool(np.array_equal(a, b))
        )
    return bool(a == b)


class WireMessage(BaseModel):
    """Base of every network message: immutable, no unknown fields, finite floats, bounded strings.

    Subclasses set `KIND` (lowercase, unique per message type); it names the message on the wire and in the
    traffic counters. Treat array fields as read-only (decoded arrays are read-only views of the payload).
    """

    model_config = ConfigDict(
        frozen=True,
        extra="forbid",
        allow_inf_nan=False,
        str_max_length=MAX_STR_LEN,
        ser_json_bytes="base64",
        val_json_bytes="base64",
    )

    KIND: ClassVar[str]

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        kind = cls.__dict__.get("KIND")
        if kind is not None and not (isinstance(kind, str) and _KIND_RE.match(kind)):
            raise TypeError(f"{cls.__name__}.KIND must match {_KIND_RE.pattern}, got {kind!r}")

    def __eq__(self, other: object) -> bool:
        # BaseModel's equality would ask numpy for the truth value of an array comparison.
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, name), getattr(other, name)) for name in type(self).model_fields)


T = TypeVar("T", bound=WireMessage)


def _kind_of(model: type[WireMessage]) -> str:
    kind = getattr(model, "KIND", None)
    if not isinstance(kind, str):
        raise TypeError(f"{model.__name__} has no KIND")
    return kind


def encode(msg: WireMessage) -> bytes:
    """The wire bytes of a message: the msgpack envelope {"v", "k", "d"}."""
    envelope = {"v": SCHEMA_VERSION, "k": _kind_of(type(msg)), "d": msg.model_dump(mode="python")}
    return msgpack.packb(envelope, use_bin_type=True)


def _reject_ext(code: int, data: bytes) -> Any:
    raise ValueError(f"msgpack extension type {code} is not allowed")


def _unpack(data: bytes | bytearray | memoryview, max_bytes: int) -> Any:
    return msgpack.unpackb(
        data,
        raw=False,
        use_list=True,
        strict_map_key=True,
        timestamp=0,
        ext_hook=_reject_ext,
        max_str_len=max_bytes,
        max_bin_len=max_bytes,
        max_array_len=min(max_bytes, MAX_CONTAINER_LEN),
        max_map_len=min(max_bytes, MAX_CONTAINER_LEN),
        max_ext_len=0,
    )


def decode(data: bytes, model: type[T], max_bytes: int = DEFAULT_MAX_BYTES) -> T:
    """Validate wire bytes into a `model` instance; raise DecodeError (only) if they are not one."""
    kind = _kind_of(model)
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DecodeError("not_msgpack", f"expected bytes, got {type(data).__name__}")
    size = memoryview(data).nbytes
    if size > max_bytes:
        raise DecodeError("too_large", f"{size} bytes > {max_bytes}")
    try:
        envelope = _unpack(data, max_bytes)
    except Exception as exc:
        raise DecodeError("not_msgpack", str(exc)[:200]) from None
    if not isinstance(envelope, dict) or envelope.keys() != _ENVELOPE_KEYS:
        raise DecodeError("bad_envelope", "expected a map with keys v, k, d")
    version, got_kind, fields = envelope["v"], envelope["k"], envelope["d"]
    if type(version) is not int or not isinstance(got_kind, str) or not isinstance(fields, dict):
        raise DecodeError("bad_envelope", "v must be an int, k a string, d a map")
    if version != SCHEMA_VERSION:
        raise DecodeError("version", f"schema version {version}, expected {SCHEMA_VERSION}")
    if got_kind != kind:
        raise DecodeError("kind", f"kind {got_kind[:40]!r}, expected {kind!r}")
    try:
        return model.model_validate(fields)
    except ValidationError as exc:
        raise DecodeError("invalid", validation_problem(exc, echo_input=False)[:200]) from None
    except Exception as exc:
        raise DecodeError("invalid", f"{type(exc).__name__}: {exc}"[:200]) from None
