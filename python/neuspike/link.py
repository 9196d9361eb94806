"""A Python node's link to a neuspike graph, over dora's Python API (``dora-rs``): what the Rust
runtime (``neuspike-runtime``) does for neuspike's own nodes, in the same protocol.

- Inputs come in order per input; a gap in sequence numbers is counted (``missing``), an input
  ends on its end-of-stream marker, and one closed without a marker (its producer died) ends
  cut short.
- Credits: when the graph gives the node an output ``credits``, the link grants each input its
  ``queue_size`` and returns credits as messages are taken; when the node's outputs are read by
  consumers that return credits (inputs fed by ``<consumer>/credits``), :meth:`Link.send` waits
  until every consumer has a credit left. Nothing then overflows a queue, so nothing is dropped.
- Outputs end with a marker carrying the count of messages their sequence numbers cover, and the
  ``cut`` flag when an input was cut short.

A test drives a node with canned events and a stand-in for dora's node (see
``examples/python-node/test_node.py``): ``Link(node, events, node_id=..., config=...)``.
"""

from __future__ import annotations

import collections
import os
import re
import time

from .messages import (
    CUT,
    Credit,
    LINK_N,
    ORIGIN_UNIX_NS,
    SEQ,
    SchemaError,
    end_of_stream,
    is_end_of_stream,
    meta_flag,
    meta_uint,
)

CREDITS = "credits"
# dora's queue size when an input does not set one.
DEFAULT_QUEUE_SIZE = 10

# The zenoh settings of every neuspike node (the Rust runtime's `ZENOH_OVERLAY`): dora sends large
# messages over zenoh with congestion control `drop`, which drops one that finds the link's 2
# real-time batches busy for 1 ms, as a loaded machine often does. With credits bounding what is
# in flight, a queue of 16 batches and a wait of up to 1 s before dropping make that path lossless
# in practice (and a loss that still happens is a counted gap).
ZENOH_OVERLAY = (
    "{ transport: { link: { tx: { queue: { size: { real_time: 16 }, "
    "congestion_control: { drop: { wait_before_drop: 1000000 } } } } } } }"
)


def init_node():
    """dora's node for this process, its zenoh session with neuspike's settings (unless
    ``DORA_ZENOH_CONFIG_OVERLAY`` already names a file): call it instead of ``dora.Node()``."""
    if "DORA_ZENOH_CONFIG_OVERLAY" not in os.environ:
        import tempfile

        fd, path = tempfile.mkstemp(prefix="neuspike-zenoh-", suffix=".json5")
        with os.fdopen(fd, "w") as f:
            f.write(ZENOH_OVERLAY)
        os.environ["DORA_ZENOH_CONFIG_OVERLAY"] = path
    else:
        path = None
    from dora import Node

    try:
        return Node()
    finally:
        if path:
            os.unlink(path)


def node_id_from_env() -> str:
    """This node's id, from the configuration dora hands every node it starts."""
    found = re.search(r"^node_id:\s*(\S+)\s*$", os.environ.get("DORA_NODE_CONFIG", ""), re.M)
    if not found:
        raise RuntimeError("not started by dora: DORA_NODE_CONFIG has no node_id")
    return found.group(1).strip("'\"")


def _source(spec) -> str:
    return spec if isinstance(spec, str) else str(spec.get("source", ""))


def _queue_size(spec) -> int:
    if isinstance(spec, dict) and spec.get("queue_size") is not None:
        return max(int(spec["queue_size"]), 1)
    return DEFAULT_QUEUE_SIZE


class _Input:
    def __init__(self):
        self.next_seq = 0
        self.received = 0
        self.missing = 0
        self.ended = False
        self.cut = False
        self.announced = 0


class Link:
    """A node's link to its graph. ``node`` sends (``send_output(id, array, metadata)``);
    ``events`` yields dora's event dicts (the node itself by default)."""

    def __init__(self, node, events=None, *, node_id=None, config=None):
        self.node = node
        self._events = iter(node if events is None else events)
        self.node_id = node_id or node_id_from_env()
        config = node.node_config() if config is None else config
        inputs = config.get("inputs", {}) or {}
        outputs = [str(o) for o in config.get("outputs", []) or []]
        self._credit_inputs = {i for i, s in inputs.items() if _source(s).endswith("/" + CREDITS)}
        # Producer side: per consumer input, None until its hello, then {output: [left, size]}.
        self._ledger = {i: None for i in self._credit_inputs}
        # Consumer side: per data input, [source, window, pending].
        self._returns = {}
        if CREDITS in outputs:
            for i, s in inputs.items():
                if i not in self._credit_inputs and "/" in _source(s) and not _source(s).startswith("dora/"):
                    self._returns[i] = [_source(s), _queue_size(s), 0]
        self._kept = collections.deque()
        self._outputs = {}
        self.inputs = {i: _Input() for i in inputs if i not in self._credit_inputs}
        self.origin_unix_ns = None
        self.cut = False
        self.stopped = False
        if self._returns:
            self._send_credit(Credit(True, [(s, w) for s, w, _ in self._returns.values()]))

    # --- credits ---------------------------------------------------------------------------

    def _send_credit(self, credit: Credit) -> None:
        meta, data = credit.to_arrow()
        self.node.send_output(CREDITS, data, meta)

    def _grant(self, input_id: str, credit: Credit) -> None:
        prefix = self.node_id + "/"
        mine = [(s[len(prefix) :], n) for s, n in credit.grants if s.startswith(prefix)]
        state = self._ledger.get(input_id, "gone")
        if state == "gone":
            return
        if credit.hello:
            if not mine and state is not None:
                return
            windows = {}
            for o, n in mine:
                w = windows.setdefault(o, [0, 0])
                w[0] += n
                w[1] += n
            self._ledger[input_id] = windows
        elif state is not None:
            for o, n in mine:
                if o in state:
                    state[o][0] = min(state[o][0] + n, state[o][1])

    def _blocked_on(self, output: str):
        for i, state in self._ledger.items():
            if state is None or (state != "gone" and output in state and state[output][0] == 0):
                return i
        return None

    def _undrained(self, output: str):
        for i, state in self._ledger.items():
            if state is None or (state != "gone" and output in state and state[output][0] < state[output][1]):
                return i
        return None

    def _absorb(self, event):
        """Takes credit events; hands every other event back."""
        kind, eid = event.get("type"), event.get("id")
        if eid in self._credit_inputs:
            if kind == "INPUT":
                try:
                    credit = Credit.from_arrow(event.get("metadata") or {}, event["value"])
                except SchemaError as e:
                    raise SchemaError(f"input `{eid}`: {e}") from None
                self._grant(eid, credit)
                return None
            if kind == "INPUT_CLOSED":
                self._ledger[eid] = "gone"
                return None
        if kind == "STOP":
            self.stopped = True
        return event

    def _next_raw(self):
        """The next event off dora's stream, or None at its end."""
        return next(self._events, None)

    def _pull(self):
        """The next event for the node (credits taken on the way), or None at the stream's end."""
        while (event := self._next_raw()) is not None:
            event = self._absorb(event)
            if event is not None:
                return event
        return None

    def _wait_for(self, test) -> None:
        """Takes events until ``test()`` holds; those not for the link are kept, in order."""
        while not test():
            event = self._next_raw()
            if event is None:
                raise RuntimeError("the graph ended while waiting for a consumer's credits")
            event = self._absorb(event)
            if event is not None:
                self._kept.append(event)

    # --- inputs ------------------------------------------------------------------------------

    def messages(self):
        """Yields ``(input_id, meta, array)`` for every message of the node's data inputs, in
        order, returning credits as each is taken, until every input has ended (or dora stops
        the node). End-of-stream markers are taken here and never yielded."""
        while not all(s.ended for s in self.inputs.values()):
            event = self._kept.popleft() if self._kept else self._pull()
            if event is None:
                break
            kind, eid = event.get("type"), event.get("id")
            if kind == "STOP":
                break
            state = self.inputs.get(eid)
            if state is None or state.ended:
                continue
            if kind == "INPUT_CLOSED":
                # Closed without its marker: the producer failed; the stream is cut short.
                state.ended = state.cut = True
                self.cut = True
                continue
            if kind != "INPUT":
                continue
            meta = dict(event.get("metadata") or {})
            meta.pop("timestamp", None)
            origin = meta.get(ORIGIN_UNIX_NS)
            if isinstance(origin, int) and not isinstance(origin, bool):
                self.origin_unix_ns = max(origin, self.origin_unix_ns or origin)
            count = is_end_of_stream(meta)
            if count is not None:
                state.ended = True
                state.announced = max(state.announced, count)
                if count > state.next_seq:
                    # Lost at the tail (their credits went with the producer's end).
                    state.missing += count - state.next_seq
                if meta_flag(meta, CUT):
                    state.cut = self.cut = True
                self._taken(eid, end=True)
                continue
            try:
                seq = meta_uint(meta, "message", SEQ)
            except SchemaError as e:
                raise SchemaError(f"input `{eid}`: {e}") from None
            if seq < state.next_seq:
                continue  # stale: a duplicate or one already counted as lost
            if seq > state.next_seq:
                state.missing += seq - state.next_seq
                if LINK_N not in meta:
                    self._lost(eid, seq - state.next_seq)
            state.next_seq = seq + 1
            state.received += 1
            self._taken(eid)
            yield eid, meta, event["value"]

    def _lost(self, input_id: str, n: int) -> None:
        r = self._returns.get(input_id)
        if r:
            r[2] += n

    def _taken(self, input_id: str, end: bool = False) -> None:
        r = self._returns.get(input_id)
        if not r:
            return
        if not end:
            r[2] += 1
        if r[2] and (end or r[2] >= (r[1] + 1) // 2):
            n, r[2] = r[2], 0
            self._send_credit(Credit(False, [(r[0], n)]))

    def missing(self) -> int:
        """Messages lost on all inputs so far."""
        return sum(s.missing for s in self.inputs.values())

    def announced(self) -> int:
        """The most messages any input's end-of-stream marker announced."""
        return max((s.announced for s in self.inputs.values()), default=0)

    # --- outputs -----------------------------------------------------------------------------

    def declare(self, output: str, message_cls) -> "Link":
        """Declares ``output`` to carry ``message_cls`` messages (Frame, Representation, ...)."""
        self._outputs[output] = {"cls": message_cls, "count": 0, "sent": 0, "ended": False}
        return self

    def send(self, output: str, message) -> None:
        """Sends ``message`` on ``output`` once every consumer of it has a credit left, stamped
        with its origin and its place among what this node sent on ``output``."""
        out = self._outputs.get(output)
        if out is None:
            raise RuntimeError(f"output `{output}` was not declared")
        if out["ended"]:
            raise RuntimeError(f"output `{output}` was sent a message after its end-of-stream marker")
        meta, data = message.to_arrow()
        seq = meta_uint(meta, "message", SEQ)
        meta[ORIGIN_UNIX_NS] = self.origin_unix_ns if self.origin_unix_ns is not None else time.time_ns()
        self._wait_for(lambda: self._blocked_on(output) is None)
        self._spend(output)
        out["count"] = max(out["count"], seq + 1)
        meta[LINK_N] = out["sent"]
        out["sent"] += 1
        self.node.send_output(output, data, meta)

    def at_least(self, output: str, count: int) -> None:
        """Makes ``output`` announce at least ``count`` messages at its end (a loss upstream is
        passed on)."""
        self._outputs[output]["count"] = max(self._outputs[output]["count"], count)

    def _spend(self, output: str) -> None:
        for state in self._ledger.values():
            if isinstance(state, dict) and output in state:
                state[output][0] = max(state[output][0] - 1, 0)

    def end_all(self) -> None:
        """Ends every output with its marker, then waits until consumers that return credits have
        taken everything (what is in flight when a process exits may be lost)."""
        for output, out in self._outputs.items():
            if out["ended"]:
                continue
            out["ended"] = True
            meta, data = end_of_stream(out["cls"], out["count"], cut=self.cut)
            meta[LINK_N] = out["sent"]
            out["sent"] += 1
            self._wait_for(lambda o=output: self._blocked_on(o) is None)
            self._spend(output)
            self.node.send_output(output, data, meta)
        for output in self._outputs:
            self._wait_for(lambda o=output: self._undrained(o) is None)
