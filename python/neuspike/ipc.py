"""A message as bytes, for links that are not dora's (zenoh): one Arrow IPC stream holding the
payload as the single column ``data`` of one record batch, the header in the schema's metadata
with typed values (``b:true``, ``i:-3``, ``f:0.5``, ``s:text``, ``o:`` another kind), and the
message type under ``neuspike.type``. The same bytes as the Rust side's ``schemas::ipc``.
"""

from __future__ import annotations

import math

import pyarrow as pa

TYPE_KEY = "neuspike.type"


class IpcError(ValueError):
    """Bytes that are not one of neuspike's messages; the text says what is wrong."""


def _typed(v) -> str:
    if isinstance(v, bool):
        return "b:" + ("true" if v else "false")
    if isinstance(v, int):
        return f"i:{v}"
    if isinstance(v, float):
        if math.isnan(v):
            return "f:NaN"
        if math.isinf(v):
            return "f:inf" if v > 0 else "f:-inf"
        return f"f:{v!r}"
    if isinstance(v, str):
        return "s:" + v
    raise IpcError(f"a header value of type {type(v).__name__} cannot travel: {v!r}")


def _untyped(key: str, v: str):
    kind, sep, text = v.partition(":")
    bad = IpcError(f"header key `{key}`: `{v[:64]}` is not a typed value (b:, i:, f:, s:, o:)")
    if not sep:
        raise bad
    try:
        if kind == "b":
            if text not in ("true", "false"):
                raise bad
            return text == "true"
        if kind == "i":
            i = int(text)
            if not -(2**63) <= i < 2**63:
                raise bad
            return i
        if kind == "f":
            return float(text)
        if kind in ("s", "o"):
            return text
    except ValueError:
        raise bad from None
    raise bad


def encode(type_urn: str, meta: dict, data: pa.Array) -> bytes:
    """The message of type ``type_urn`` with header ``meta`` and payload ``data``."""
    md = {k: _typed(v) for k, v in meta.items()}
    md[TYPE_KEY] = type_urn
    schema = pa.schema([pa.field("data", data.type, nullable=True)], metadata=md)
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, schema) as w:
        w.write_batch(pa.record_batch([data], schema=schema))
    return sink.getvalue().to_pybytes()


def decode(data: bytes):
    """``(type_urn, meta, array)`` from :func:`encode`'s bytes; :class:`IpcError` otherwise.
    pyarrow reads the buffers in place and the batch is validated in full before use."""
    try:
        reader = pa.ipc.open_stream(pa.py_buffer(data))
        batches = list(reader)
        schema = reader.schema
    except (pa.ArrowException, ValueError, OSError) as e:
        raise IpcError(f"not an Arrow IPC message: {e}") from None
    if len(batches) != 1:
        raise IpcError(
            "an Arrow IPC message holds one batch of one column `data`; found "
            + ("no batch" if not batches else "more than one batch")
        )
    batch = batches[0]
    if batch.num_columns != 1 or schema.field(0).name != "data":
        raise IpcError(
            f"an Arrow IPC message holds one batch of one column `data`; found {batch.num_columns} columns"
        )
    try:
        batch.validate(full=True)
    except (pa.ArrowException, ValueError) as e:
        raise IpcError(f"not an Arrow IPC message: {e}") from None
    urn = None
    meta = {}
    for k, v in (schema.metadata or {}).items():
        try:
            k, v = k.decode(), v.decode()
        except UnicodeDecodeError:
            raise IpcError("a header key or value is not UTF-8") from None
        if k == TYPE_KEY:
            urn = v
        else:
            meta[k] = _untyped(k, v)
    if urn is None:
        raise IpcError(f"the header has no `{TYPE_KEY}`")
    return urn, meta, batch.column(0)
