"""neuspike's messages and node protocol for Python nodes (pyarrow, numpy; dora-rs to run).

- :mod:`neuspike.messages`: Frame, Representation, SpikeChunk, EventBatch, Credit, end-of-stream
  markers; the layouts, header keys and errors of the Rust crate ``neuspike-schemas``.
- :mod:`neuspike.ipc`: a message as Arrow IPC bytes, as neuspike publishes it on zenoh.
- :mod:`neuspike.link`: a node's link to its graph (order, loss counting, credits, markers).
"""

from .ipc import IpcError, decode, encode
from .link import Link
from .messages import (
    VERSION,
    Credit,
    EventBatch,
    Frame,
    Representation,
    SchemaError,
    SpikeChunk,
    end_of_stream,
    is_end_of_stream,
)

__all__ = [
    "VERSION",
    "Credit",
    "EventBatch",
    "Frame",
    "IpcError",
    "Link",
    "Representation",
    "SchemaError",
    "SpikeChunk",
    "decode",
    "encode",
    "end_of_stream",
    "is_end_of_stream",
]
