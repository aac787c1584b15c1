"""Network messages: pydantic models <-> msgpack, with a schema version.

Every message on the bus is a `WireMessage` subclass with a `KIND`. On the wire it is one msgpack map,
the envelope ``{"v": SCHEMA_VERSION, "k": KIND, "d": <fields>}``. `decode` treats its input as hostile:
the size is checked before unpacking, then the structure (`check_structure`: nesting depth and the sum of the
declared container lengths, walked over the headers without building anything), then msgpack runs with bounded
lengths and no extension types, and the fields are validated by the model (finite floats, bounded strings,
bounded arrays). Whatever the input,
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
# Bounds the element count of any one msgpack array or map. msgpack allocates for the count it reads before the
# elements arrive; `check_structure` first makes sure every count is backed by bytes of the input. Big numeric
# data belongs in an NDArray. Strings and bytes are bounded by the input itself.
MAX_CONTAINER_LEN = 1 << 14
MAX_STR_LEN = 4096  # default bound of every str field; a field may set its own max_length
# Bounds of a message's structure, checked before msgpack builds anything (`check_structure`). The deepest
# message is 8 levels (envelope, fields, holdings, entries, entry, ranges, range); the most items a legitimate
# message declares is 19,501 (a heartbeat whose holdings are at every bound of swarm.bus.holdings).
MAX_DEPTH = 16
MAX_ITEMS = 1 << 15

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


# check_structure's tables, by a value's first byte. _FIXED: the whole size of a value whose size the first
# byte tells (fixint, nil, bool, float, int, fixstr), else 0. _CONTAINER: (bytes of the length field, items
# per entry: 2 for a map's key and value) of an array or map header. _SIZED: bytes of the length field of a
# str or bin. A byte in none of them (0xc1, every extension type) is refused.
_FIXED_SIZES = {0xC0: 1, 0xC2: 1, 0xC3: 1, 0xCA: 5, 0xCB: 9, 0xCC: 2, 0xCD: 3, 0xCE: 5, 0xCF: 9}
_FIXED_SIZES |= {0xD0: 2, 0xD1: 3, 0xD2: 5, 0xD3: 9}
_FIXED = tuple(
    1 if b < 0x80 or b >= 0xE0 else 1 + (b & 0x1F) if 0xA0 <= b < 0xC0 else _FIXED_SIZES.get(b, 0) for b in range(256)
)
_CONTAINER_HEADERS = {0xDC: (2, 1), 0xDD: (4, 1), 0xDE: (2, 2), 0xDF: (4, 2)}
_CONTAINER = tuple(
    (0, 2) if 0x80 <= b < 0x90 else (0, 1) if 0x90 <= b < 0xA0 else _CONTAINER_HEADERS.get(b) for b in range(256)
)
_SIZED = {0xC4: 1, 0xC5: 2, 0xC6: 4, 0xD9: 1, 0xDA: 2, 0xDB: 4}


def check_structure(
    data: bytes | bytearray | memoryview, max_depth: int = MAX_DEPTH, max_items: int = MAX_ITEMS
) -> None:
    """Raise DecodeError("not_msgpack") unless `data` is one msgpack value nested at most `max_depth` containers
    deep whose containers declare at most min(`max_items`, len(data)) items in all (a map's entry is two).

    Why: msgpack allocates every array it reads a header for, at the length the header claims, before the items
    arrive, at each of up to 1024 levels. 3 kB of nested array headers cost 70-80 ms of CPU with the GIL held
    (measured on the 2-core machine) and are then rejected anyway; about 20 such heartbeats a second starve the
    event loop that flies the drone. Every item takes at least one byte, so a document declaring more items than
    it has bytes is a lie, and once this check has passed msgpack allocates at most 8 bytes per input byte.
    msgpack-python has no option for depth or total length (only per-container ones), so this walks the headers
    by hand: str, bin and scalars are skipped by their size, nothing is built, and the walk stops at the first
    bound crossed. Cost: about 0.13 us per item (2.5 ms for the largest legitimate heartbeat, 20 us for a
    typical one, 3 us for a patch chunk). It does not check what msgpack checks anyway (UTF-8, map keys).
    """
    view = data if isinstance(data, bytes) else bytes(data)
    end = len(view)
    budget = min(max_items, end)
    pos = 0
    left = 1  # items still to read in the innermost open container (the top level: one value)
    stack: list[int] = []  # the items left in each enclosing container
    fixed, container = _FIXED, _CONTAINER
    try:
        while True:
            first = view[pos]
            size = fixed[first]
            if size:
                pos += size
            elif (header := container[first]) is not None:
                width, per = header
                count = int.from_bytes(view[pos + 1 : pos + 1 + width], "big") if width else first & 0x0F
                pos += 1 + width
                if count:
                    budget -= count * per
                    if budget < 0:
                        raise DecodeError("not_msgpack", f"more than {min(max_items, end)} items declared")
                    if len(stack) >= max_depth:
                        raise DecodeError("not_msgpack", f"nested more than {max_depth} deep")
                    stack.append(left - 1)
                    left = count * per
                    continue
            elif (length_bytes := _SIZED.get(first)) is not None:
                pos += 1 + length_bytes + int.from_bytes(view[pos + 1 : pos + 1 + length_bytes], "big")
            else:
                raise DecodeError("not_msgpack", f"byte 0x{first:02x} at {pos} starts no allowed msgpack value")
            left -= 1
            while not left:
                if not stack:
                    if pos < end:
                        raise DecodeError("not_msgpack", f"{end - pos} bytes after the message")
                    if pos > end:
                        raise IndexError
                    return
                left = stack.pop()
    except IndexError:
        raise DecodeError("not_msgpack", "truncated") from None


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
    check_structure(data)
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
