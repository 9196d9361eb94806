"""neuspike's messages in Python: the same Arrow layouts, header keys, field names and errors as
the Rust crate `neuspike-schemas` (contract `neuspike/messages/v1`).

Each message class has ``to_arrow() -> (meta, array)`` and ``from_arrow(meta, array)``. ``meta``
is the header, a dict of bool, int, float and str values, exactly what dora's Python API gives
and takes as an input's metadata. Decoding checks every key and the payload against the header
and raises :class:`SchemaError` with the text the Rust side gives for the same fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from decimal import Decimal
from typing import Optional

import numpy as np
import pyarrow as pa

VERSION = "neuspike/messages/v1"

# Header keys (schemas/src/meta.rs).
WIDTH = "width"
HEIGHT = "height"
SEQ = "seq"
FIRST_PLANE = "first_plane"
N_PLANES = "n_planes"
T_FIRST_NS = "t_first_ns"
PLANE_PERIOD_NS = "plane_period_ns"
T_START_NS = "t_start_ns"
T_END_NS = "t_end_ns"
T_REF_NS = "t_ref_ns"
REF_PLANE = "ref_plane"
KIND = "kind"
CHANNELS = "channels"
METHOD = "method"
COMPUTE_NS = "compute_ns"
CHOSEN = "chosen"
BUDGET_NS = "budget_ns"
PARAM_PREFIX = "param."
LUM_PER_RATE = "lum_per_rate"
EOS = "eos"
COUNT = "count"
LINK_N = "link_n"
CUT = "cut"
ORIGIN_UNIX_NS = "origin_unix_ns"
HELLO = "hello"

REPRESENTATION_KINDS = (
    "tfp",
    "isi",
    "spike_repr",
    "event_integration",
    "stp",
    "voxel_grid",
    "event_stack",
    "time_surface",
)

I64_MIN, I64_MAX = -(2**63), 2**63 - 1


class SchemaError(ValueError):
    """Why a message could not be decoded; the text names the message, the key or column, and
    the value found, as the Rust side's ``SchemaError`` does."""

    @classmethod
    def missing_key(cls, message: str, key: str) -> "SchemaError":
        return cls(f"{message}: metadata key `{key}` is missing")

    @classmethod
    def bad_key(cls, message: str, key: str, expected: str, found: str) -> "SchemaError":
        return cls(f"{message}: metadata key `{key}` is {found}, expected {expected}")

    @classmethod
    def bad_type(cls, message: str, expected: str, found: str) -> "SchemaError":
        return cls(f"{message}: payload has Arrow type {found}, expected {expected}")

    @classmethod
    def inconsistent(cls, message: str, what: str) -> "SchemaError":
        return cls(f"{message}: {what}")


# --- Rust's way of writing values, so that errors read the same -----------------------------

_ARROW_NAMES = {
    pa.int8(): "Int8",
    pa.int16(): "Int16",
    pa.int32(): "Int32",
    pa.int64(): "Int64",
    pa.uint8(): "UInt8",
    pa.uint16(): "UInt16",
    pa.uint32(): "UInt32",
    pa.uint64(): "UInt64",
    pa.float16(): "Float16",
    pa.float32(): "Float32",
    pa.float64(): "Float64",
    pa.bool_(): "Boolean",
    pa.utf8(): "Utf8",
    pa.large_utf8(): "LargeUtf8",
    pa.binary(): "Binary",
    pa.large_binary(): "LargeBinary",
    pa.null(): "Null",
}


def arrow_name(t: pa.DataType) -> str:
    """An Arrow type as the Rust arrow crate displays it (primitive types exactly)."""
    return _ARROW_NAMES.get(t, str(t))


def rust_float(f: float) -> str:
    """A float as Rust's ``Display`` writes it: no exponent, ``NaN``, ``inf``, integers bare."""
    if math.isnan(f):
        return "NaN"
    if math.isinf(f):
        return "inf" if f > 0 else "-inf"
    text = format(Decimal(repr(float(f))), "f")
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text == "-0" and math.copysign(1.0, f) > 0 else text


def rust_f32(v: np.float32) -> str:
    """An f32 as Rust's ``Display`` writes it (shortest text that reads back as the same f32)."""
    f = float(v)
    if not math.isfinite(f):
        return rust_float(f)
    return rust_float(float(np.format_float_positional(np.float32(v), unique=True, trim="-")))


def _rust_debug_str(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\r":
            out.append("\\r")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{{{ord(ch):x}}}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def describe(v) -> str:
    """A header value as the Rust side names it in errors."""
    if isinstance(v, bool):
        return f"the bool {'true' if v else 'false'}"
    if isinstance(v, int):
        return f"the integer {v}"
    if isinstance(v, float):
        return f"the float {rust_float(v)}"
    if isinstance(v, str):
        return f"the string {_rust_debug_str(v)}"
    return repr(v)


# --- typed header access (MetaExt) ----------------------------------------------------------


def meta_int(m: dict, message: str, key: str) -> int:
    if key not in m:
        raise SchemaError.missing_key(message, key)
    v = m[key]
    if isinstance(v, bool) or not isinstance(v, int) or not I64_MIN <= v <= I64_MAX:
        raise SchemaError.bad_key(message, key, "an integer", describe(v))
    return v


def meta_uint(m: dict, message: str, key: str) -> int:
    v = meta_int(m, message, key)
    if v < 0:
        raise SchemaError.bad_key(message, key, "a non-negative integer", str(v))
    return v


def meta_size(m: dict, message: str, key: str) -> int:
    v = meta_int(m, message, key)
    if not 0 <= v <= 0xFFFF_FFFF:
        raise SchemaError.bad_key(message, key, "a size in 0..=4294967295", str(v))
    return v


def meta_string(m: dict, message: str, key: str) -> str:
    if key not in m:
        raise SchemaError.missing_key(message, key)
    v = m[key]
    if not isinstance(v, str):
        raise SchemaError.bad_key(message, key, "a string", describe(v))
    return v


def meta_float(m: dict, message: str, key: str) -> float:
    if key not in m:
        raise SchemaError.missing_key(message, key)
    v = m[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SchemaError.bad_key(message, key, "a number", describe(v))
    return float(v)


def meta_flag(m: dict, key: str) -> bool:
    return m.get(key) is True


def meta_lum_per_rate(m: dict, message: str):
    if LUM_PER_RATE not in m:
        return None
    g = meta_float(m, message, LUM_PER_RATE)
    if not (math.isfinite(g) and g > 0.0):
        raise SchemaError.bad_key(message, LUM_PER_RATE, "a positive finite number", rust_float(g))
    return g


def _check_type(message: str, expected: pa.DataType, found: pa.DataType) -> None:
    if not found.equals(expected):
        raise SchemaError.bad_type(message, arrow_name(expected), arrow_name(found))


def _floats(message: str, data: pa.Array) -> np.ndarray:
    _check_type(message, pa.float32(), data.type)
    if data.null_count:
        raise SchemaError.inconsistent(message, f"payload has {data.null_count} nulls")
    return data.to_numpy(zero_copy_only=False)


def _finite(message: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raise SchemaError.inconsistent(
            message,
            f"value {i} is {rust_f32(values[i])} (NaN or infinite values never travel)",
        )


def _f32_payload(values: np.ndarray) -> pa.Array:
    return pa.array(np.ascontiguousarray(values, dtype=np.float32).ravel(), type=pa.float32())


# --- the messages ---------------------------------------------------------------------------


@dataclass
class Frame:
    """A luminance frame ``[H, W]`` in [0, 1] at ``t_ref_ns``."""

    TYPE_URN = "neuspike/messages/v1/Frame"
    DATA_TYPE = pa.float32()

    kind: str  # "reconstruction" or "ground-truth"
    method: str
    t_ref_ns: int
    compute_ns: int
    seq: int
    data: np.ndarray  # float32 [H, W]
    chosen: Optional[str] = None  # the method `auto` chose; absent otherwise
    budget_ns: Optional[int] = None  # `auto`'s deadline in budget mode; absent otherwise

    def to_arrow(self):
        h, w = self.data.shape
        meta = {
            KIND: self.kind,
            METHOD: self.method,
            WIDTH: int(w),
            HEIGHT: int(h),
            T_REF_NS: int(self.t_ref_ns),
            COMPUTE_NS: int(self.compute_ns),
            SEQ: int(self.seq),
        }
        if self.chosen is not None:
            meta[CHOSEN] = self.chosen
        if self.budget_ns is not None:
            meta[BUDGET_NS] = int(self.budget_ns)
        return meta, _f32_payload(self.data)

    @classmethod
    def from_arrow(cls, m: dict, data: pa.Array) -> "Frame":
        name = "frame"
        values = _floats(name, data)
        h = meta_size(m, name, HEIGHT)
        w = meta_size(m, name, WIDTH)
        if len(values) != h * w:
            raise SchemaError.inconsistent(name, f"payload has {len(values)} values, header says {h}x{w}")
        _finite(name, values)
        kind = meta_string(m, name, KIND)
        if kind not in ("reconstruction", "ground-truth"):
            raise SchemaError.bad_key(name, KIND, "`reconstruction` or `ground-truth`", kind)
        return cls(
            kind=kind,
            method=meta_string(m, name, METHOD),
            t_ref_ns=meta_int(m, name, T_REF_NS),
            compute_ns=meta_int(m, name, COMPUTE_NS),
            seq=meta_uint(m, name, SEQ),
            data=values.reshape(h, w),
            chosen=meta_string(m, name, CHOSEN) if CHOSEN in m else None,
            budget_ns=meta_int(m, name, BUDGET_NS) if BUDGET_NS in m else None,
        )


@dataclass
class Representation:
    """A representation tensor ``[C, H, W]`` computed at ``t_ref_ns``."""

    TYPE_URN = "neuspike/messages/v1/Representation"
    DATA_TYPE = pa.float32()

    kind: str  # one of REPRESENTATION_KINDS
    t_ref_ns: int
    seq: int
    data: np.ndarray  # float32 [C, H, W]
    params: dict = field(default_factory=dict)

    def to_arrow(self):
        c, h, w = self.data.shape
        meta = {
            KIND: self.kind,
            CHANNELS: int(c),
            HEIGHT: int(h),
            WIDTH: int(w),
            T_REF_NS: int(self.t_ref_ns),
            SEQ: int(self.seq),
        }
        for k, v in self.params.items():
            meta[PARAM_PREFIX + k] = float(v)
        return meta, _f32_payload(self.data)

    @classmethod
    def from_arrow(cls, m: dict, data: pa.Array) -> "Representation":
        name = "representation"
        values = _floats(name, data)
        c = meta_size(m, name, CHANNELS)
        h = meta_size(m, name, HEIGHT)
        w = meta_size(m, name, WIDTH)
        if len(values) != c * h * w:
            raise SchemaError.inconsistent(
                name, f"payload has {len(values)} values, header says {c}x{h}x{w} = {c * h * w}"
            )
        _finite(name, values)
        params = {}
        for k in sorted(m):
            if k.startswith(PARAM_PREFIX):
                v = m[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise SchemaError.inconsistent(name, f"parameter `{k}` is {v!r}, expected a number")
                params[k[len(PARAM_PREFIX) :]] = float(v)
        kind = meta_string(m, name, KIND)
        if kind not in REPRESENTATION_KINDS:
            raise SchemaError.bad_key(
                name,
                KIND,
                "a representation kind",
                f"{_rust_debug_str(kind)} (not one of {', '.join(REPRESENTATION_KINDS)})",
            )
        return cls(
            kind=kind,
            t_ref_ns=meta_int(m, name, T_REF_NS),
            seq=meta_uint(m, name, SEQ),
            data=values.reshape(c, h, w),
            params=params,
        )


def bytes_per_plane(width: int, height: int) -> int:
    return (width * height + 7) // 8


@dataclass
class SpikeChunk:
    """``n_planes`` spike planes, bit-packed row-major, pixel ``k = y * width + x`` at bit
    ``k & 7`` (least significant first) of byte ``k >> 3`` of its plane."""

    TYPE_URN = "neuspike/messages/v1/SpikeChunk"
    DATA_TYPE = pa.uint8()

    width: int
    height: int
    first_plane: int
    n_planes: int
    t_first_ns: int
    plane_period_ns: int
    seq: int
    bits: bytes
    lum_per_rate: float | None = None

    def planes(self) -> np.ndarray:
        """The planes unpacked, ``[n_planes, height, width]`` of 0 and 1 (uint8)."""
        per = bytes_per_plane(self.width, self.height)
        raw = np.frombuffer(self.bits, dtype=np.uint8).reshape(self.n_planes, per)
        bits = np.unpackbits(raw, axis=1, bitorder="little")[:, : self.width * self.height]
        return bits.reshape(self.n_planes, self.height, self.width)

    @classmethod
    def from_planes(cls, planes: np.ndarray, **header) -> "SpikeChunk":
        """Packs ``[n, height, width]`` planes of 0 and 1."""
        n, h, w = planes.shape
        flat = (np.asarray(planes) != 0).reshape(n, h * w).astype(np.uint8)
        packed = np.packbits(flat, axis=1, bitorder="little")
        return cls(width=w, height=h, n_planes=n, bits=packed.tobytes(), **header)

    def to_arrow(self):
        meta = {
            WIDTH: int(self.width),
            HEIGHT: int(self.height),
            FIRST_PLANE: int(self.first_plane),
            N_PLANES: int(self.n_planes),
            T_FIRST_NS: int(self.t_first_ns),
            PLANE_PERIOD_NS: int(self.plane_period_ns),
            SEQ: int(self.seq),
        }
        if self.lum_per_rate is not None:
            meta[LUM_PER_RATE] = float(self.lum_per_rate)
        return meta, pa.array(np.frombuffer(self.bits, dtype=np.uint8), type=pa.uint8())

    @classmethod
    def from_arrow(cls, m: dict, data: pa.Array) -> "SpikeChunk":
        name = "spike chunk"
        _check_type(name, pa.uint8(), data.type)
        width = meta_size(m, name, WIDTH)
        height = meta_size(m, name, HEIGHT)
        n_planes = meta_size(m, name, N_PLANES)
        first_plane = meta_uint(m, name, FIRST_PLANE)
        t_first_ns = meta_int(m, name, T_FIRST_NS)
        plane_period_ns = meta_int(m, name, PLANE_PERIOD_NS)
        seq = meta_uint(m, name, SEQ)
        if width == 0 or height == 0:
            raise SchemaError.inconsistent(name, f"empty sensor {width}x{height}")
        if plane_period_ns <= 0:
            raise SchemaError.bad_key(name, PLANE_PERIOD_NS, "a positive period", str(plane_period_ns))
        expected = n_planes * bytes_per_plane(width, height)
        if data.null_count:
            raise SchemaError.inconsistent(name, f"payload has {data.null_count} null bytes")
        if len(data) != expected:
            raise SchemaError.inconsistent(
                name,
                f"payload has {len(data)} bytes, header says {n_planes} planes of "
                f"{width}x{height} = {expected} bytes",
            )
        return cls(
            width=width,
            height=height,
            first_plane=first_plane,
            n_planes=n_planes,
            t_first_ns=t_first_ns,
            plane_period_ns=plane_period_ns,
            seq=seq,
            bits=data.to_numpy(zero_copy_only=False).tobytes(),
            lum_per_rate=meta_lum_per_rate(m, name),
        )


EVENT_FIELDS = [
    pa.field("t_ns", pa.int64(), nullable=False),
    pa.field("x", pa.uint16(), nullable=False),
    pa.field("y", pa.uint16(), nullable=False),
    pa.field("polarity", pa.int8(), nullable=False),
]
EVENT_TYPE = pa.struct(EVENT_FIELDS)


@dataclass
class EventBatch:
    """The DVS events of ``[t_start_ns, t_end_ns)``, sorted by time, as columns."""

    TYPE_URN = "neuspike/messages/v1/EventBatch"
    DATA_TYPE = EVENT_TYPE

    width: int
    height: int
    t_start_ns: int
    t_end_ns: int
    seq: int
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    x: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint16))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint16))
    polarity: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))

    def __len__(self) -> int:
        return len(self.t_ns)

    def to_arrow(self):
        meta = {
            WIDTH: int(self.width),
            HEIGHT: int(self.height),
            T_START_NS: int(self.t_start_ns),
            T_END_NS: int(self.t_end_ns),
            SEQ: int(self.seq),
        }
        cols = [
            pa.array(np.asarray(self.t_ns, np.int64), pa.int64()),
            pa.array(np.asarray(self.x, np.uint16), pa.uint16()),
            pa.array(np.asarray(self.y, np.uint16), pa.uint16()),
            pa.array(np.asarray(self.polarity, np.int8), pa.int8()),
        ]
        return meta, pa.StructArray.from_arrays(cols, fields=EVENT_FIELDS)

    def validate(self, message: str = "event batch") -> None:
        """Checks coordinates, polarities, order and interval; errors name the event and value."""
        if self.t_end_ns < self.t_start_ns:
            raise SchemaError.inconsistent(
                message, f"interval [{self.t_start_ns}, {self.t_end_ns}) ends before it starts"
            )
        n = len(self.t_ns)
        if not len(self.x) == len(self.y) == len(self.polarity) == n:
            raise SchemaError.inconsistent(message, "event columns differ in length")
        t = np.asarray(self.t_ns, np.int64)
        x = np.asarray(self.x)
        y = np.asarray(self.y)
        p = np.asarray(self.polarity)
        prev = np.concatenate([[I64_MIN], t[:-1]]) if n else t
        bad = (x >= self.width) | (y >= self.height) | ((p != 1) & (p != -1)) | (t < prev)
        bad |= (t < self.t_start_ns) | (t >= self.t_end_ns)
        hits = np.flatnonzero(bad)
        if not hits.size:
            return
        i = int(hits[0])
        if x[i] >= self.width or y[i] >= self.height:
            what = f"event {i} at ({x[i]}, {y[i]}) is outside the {self.width}x{self.height} sensor"
        elif p[i] not in (1, -1):
            what = f"event {i} has polarity {p[i]}, expected +1 or -1"
        elif t[i] < prev[i]:
            what = f"event {i} at t_ns {t[i]} is earlier than event {i - 1} at {prev[i]}"
        else:
            what = (
                f"event {i} at t_ns {t[i]} is outside the batch interval "
                f"[{self.t_start_ns}, {self.t_end_ns})"
            )
        raise SchemaError.inconsistent(message, what)

    @classmethod
    def from_arrow(cls, m: dict, data: pa.Array) -> "EventBatch":
        name = "event batch"
        _check_type(name, EVENT_TYPE, data.type)
        b = cls(
            width=meta_size(m, name, WIDTH),
            height=meta_size(m, name, HEIGHT),
            t_start_ns=meta_int(m, name, T_START_NS),
            t_end_ns=meta_int(m, name, T_END_NS),
            seq=meta_uint(m, name, SEQ),
        )
        cols = [data.field(f.name) for f in EVENT_FIELDS]
        if data.null_count or any(c.null_count for c in cols):
            raise SchemaError.inconsistent(name, "events contain nulls")
        b.t_ns, b.x, b.y, b.polarity = (c.to_numpy(zero_copy_only=False) for c in cols)
        b.validate(name)
        return b


CREDIT_FIELDS = [
    pa.field("source", pa.utf8(), nullable=False),
    pa.field("credits", pa.uint64(), nullable=False),
]
CREDIT_TYPE = pa.struct(CREDIT_FIELDS)


@dataclass
class Credit:
    """Credits a consumer returns: for each input, named by its source ``node/output``, how many
    more messages it can take. The first one (``hello``) lists every input with its window."""

    TYPE_URN = "neuspike/messages/v1/Credit"
    DATA_TYPE = CREDIT_TYPE

    hello: bool
    grants: list  # [(source, credits)]

    def to_arrow(self):
        sources = pa.array([s for s, _ in self.grants], pa.utf8())
        credits = pa.array([int(n) for _, n in self.grants], pa.uint64())
        return {HELLO: bool(self.hello)}, pa.StructArray.from_arrays(
            [sources, credits], fields=CREDIT_FIELDS
        )

    @classmethod
    def from_arrow(cls, m: dict, data: pa.Array) -> "Credit":
        name = "credit"
        _check_type(name, CREDIT_TYPE, data.type)
        sources, credits = data.field("source"), data.field("credits")
        if data.null_count or sources.null_count or credits.null_count:
            raise SchemaError.inconsistent(name, "a grant is null")
        return cls(hello=meta_flag(m, HELLO), grants=list(zip(sources.to_pylist(), credits.to_pylist())))


MESSAGES = {cls.TYPE_URN: cls for cls in (Frame, Representation, SpikeChunk, EventBatch, Credit)}


# --- sequence numbers and end-of-stream markers ---------------------------------------------


def end_of_stream(message_cls, count: int, cut: bool = False):
    """The end-of-stream marker of an output that sent ``count`` messages (sequence numbers
    ``0..count``): an empty payload of the stream's type, ``eos = true``, ``count``; flagged
    ``cut`` when the stream was cut short."""
    meta = {EOS: True, COUNT: min(int(count), I64_MAX)}
    if cut:
        meta[CUT] = True
    return meta, pa.array([], type=message_cls.DATA_TYPE)


def is_end_of_stream(meta: dict):
    """``count`` when the message is an end-of-stream marker, else ``None``."""
    if not meta_flag(meta, EOS):
        return None
    c = meta.get(COUNT)
    return c if isinstance(c, int) and not isinstance(c, bool) and c >= 0 else 0
