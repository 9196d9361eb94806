//! The receive loop: every input's sequence numbers and end-of-stream marker, accounted once.

use std::collections::BTreeMap;
use std::time::Instant;

use dora_node_api::Event;
use neuspike_schemas::arrow::array::ArrayRef;
use neuspike_schemas::meta::{CUT, LINK_N, SEQ};
use neuspike_schemas::{Meta, MetaExt, SeqStatus, SeqTracker, is_end_of_stream};

use crate::link::Polled;
use crate::metadata::meta_from_dora;
use crate::reorder::{Pushed, Reorder};
use crate::{Flow, Link};

/// What the receive loop hands a node.
#[derive(Debug)]
pub enum Received<'a> {
    /// A message on `input` (never an end-of-stream marker); its sequence number is already
    /// accounted for.
    Message {
        /// The input's id in the graph.
        input: &'a str,
        /// The message's header.
        meta: &'a Meta,
        /// The message's payload.
        data: &'a ArrayRef,
    },
    /// The end-of-stream marker of `input`: its sender sent `count` messages.
    End {
        /// The input's id in the graph.
        input: &'a str,
        /// How many messages the sender announced.
        count: u64,
    },
}

/// One input's stream: its sequence numbers and whether its end-of-stream marker came.
#[derive(Clone, Debug, Default)]
pub struct InputState {
    /// The input's sequence numbers: received, missing, stale, announced.
    pub seq: SeqTracker,
    /// Whether the stream ended: its end-of-stream marker arrived, or dora closed it and
    /// nothing came for [`CLOSE_GRACE`] (then `broken` too).
    pub ended: bool,
    /// The [`LINK_N`] the next message should carry.
    next_link_n: u64,
    /// Whether it was cut short: it ended without its marker (its sender failed), or its marker
    /// said a node upstream failed.
    pub broken: bool,
}

/// A message held until its turn: its header and payload.
type Held = (Meta, ArrayRef);

/// The inputs a node reads, and the state of each.
#[derive(Debug, Default)]
pub struct Inputs {
    streams: BTreeMap<String, InputState>,
    /// Messages that came before their turn, by input.
    waiting: BTreeMap<String, Reorder<Held>>,
    /// Inputs dora closed before their marker, and when.
    closed: BTreeMap<String, Instant>,
}

/// How long an input dora closed before its end-of-stream marker came may still deliver (dora
/// may say an input closed before its last messages); after that its sender is taken to have
/// failed and the input ends, so that a node whose producer died finishes within seconds.
pub const CLOSE_GRACE: std::time::Duration = std::time::Duration::from_secs(1);

impl Inputs {
    /// The inputs `ids` (the node's declared inputs, or those its method reads). Messages on any
    /// other input are logged and ignored.
    pub fn new<S: AsRef<str>>(ids: impl IntoIterator<Item = S>) -> Self {
        Inputs {
            streams: ids
                .into_iter()
                .map(|id| (id.as_ref().to_string(), InputState::default()))
                .collect(),
            waiting: BTreeMap::new(),
            closed: BTreeMap::new(),
        }
    }

    /// The state of input `id`, if the node reads it.
    pub fn get(&self, id: &str) -> Option<&InputState> {
        self.streams.get(id)
    }

    /// Every input's id and state, sorted by id.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &InputState)> {
        self.streams.iter().map(|(k, v)| (k.as_str(), v))
    }

    /// Whether every input has ended (true for a node that reads none).
    pub fn all_ended(&self) -> bool {
        self.streams.values().all(|s| s.ended)
    }

    /// Messages known to be missing, over every input.
    pub fn missing(&self) -> u64 {
        self.streams.values().map(|s| s.seq.missing()).sum()
    }

    /// The largest count announced by an end-of-stream marker (0 before any).
    pub fn announced(&self) -> u64 {
        self.streams
            .values()
            .filter_map(|s| s.seq.announced())
            .max()
            .unwrap_or(0)
    }

    /// Accounts for one received message: `Ok(None)` when the input is not read by the node.
    /// Takes a message of `input` off dora's queue: held until its turn (see [`Reorder`]).
    /// `false` for an input the node does not read, or a message whose turn has passed.
    fn arrive(
        &mut self,
        input: &str,
        meta: Meta,
        data: ArrayRef,
        now: Instant,
    ) -> eyre::Result<bool> {
        let Some(state) = self.streams.get_mut(input) else {
            tracing::warn!(input, "input not read by this node: ignored");
            return Ok(false);
        };
        if state.ended {
            tracing::warn!(input, "a message after the end-of-stream marker: ignored");
            return Ok(false);
        }
        // Its place among what the sender sent; from a sender that does not count, its sequence
        // number (a marker's: the count it announces, after every message).
        let pos = match (meta.get(LINK_N), is_end_of_stream(&meta)) {
            (Some(neuspike_schemas::Parameter::Integer(n)), _) if *n >= 0 => *n as u64,
            (_, Some(count)) => count,
            _ => meta
                .uint("message", SEQ)
                .map_err(|e| eyre::eyre!("input `{input}`: {e}"))?,
        };
        let seq = meta.uint("message", SEQ).ok();
        let queue = self.waiting.entry(input.to_string()).or_default();
        match queue.push(pos, (meta, data), now) {
            Pushed::Held => Ok(true),
            Pushed::Late => {
                if let Some(seq) = seq {
                    let _ = state.seq.observe(seq);
                }
                tracing::warn!(input, ?seq, "a message came after its turn: dropped");
                Ok(false)
            }
        }
    }

    /// The next message whose turn has come, on any input (all that is held when `flush`).
    fn next_due(&mut self, now: Instant, flush: bool) -> Option<(String, Held)> {
        let closed = &self.closed;
        self.waiting.iter_mut().find_map(|(input, queue)| {
            // A closed input past its grace hands over all it holds.
            let expired = closed.get(input).is_some_and(|t| now >= *t + CLOSE_GRACE);
            let popped = if flush || expired {
                queue.pop_any()
            } else {
                queue.pop(now)
            };
            popped.map(|(_, held)| (input.clone(), held))
        })
    }

    /// When the first held message stops waiting for the ones before it, or a closed input's
    /// grace runs out.
    fn deadline(&self) -> Option<Instant> {
        let closing = self.closed.values().map(|t| *t + CLOSE_GRACE);
        self.waiting
            .values()
            .filter_map(Reorder::deadline)
            .chain(closing)
            .min()
    }

    /// dora closed `input`: unless its marker comes within [`CLOSE_GRACE`], it ends broken.
    fn close(&mut self, input: &str, now: Instant) {
        if self.streams.get(input).is_some_and(|s| !s.ended) {
            self.closed.entry(input.to_string()).or_insert(now);
        }
    }

    /// The sender of `input` was restarted: a close seen before is forgotten, and the new
    /// process counts what it sends from 0.
    fn reopen(&mut self, input: &str) {
        self.closed.remove(input);
        if let Some(s) = self.streams.get_mut(input) {
            s.next_link_n = 0;
        }
        if let Some(q) = self.waiting.get_mut(input) {
            q.restart();
        }
    }

    /// Ends the closed inputs whose grace ran out, once what they hold is handed over; returns
    /// each with the count of messages it covered (received and missing).
    fn expire(&mut self, now: Instant) -> Vec<(String, u64)> {
        let mut ended = Vec::new();
        let due: Vec<String> = self
            .closed
            .iter()
            .filter(|(_, t)| now >= **t + CLOSE_GRACE)
            .map(|(k, _)| k.clone())
            .collect();
        for input in due {
            if self.waiting.get(&input).is_some_and(|q| !q.is_empty()) {
                continue;
            }
            self.closed.remove(&input);
            if let Some(state) = self.streams.get_mut(&input)
                && !state.ended
            {
                tracing::error!(
                    input,
                    "input closed without its end-of-stream marker: its sender failed"
                );
                state.ended = true;
                state.broken = true;
                ended.push((input, state.seq.received() + state.seq.missing()));
            }
        }
        ended
    }

    /// Accounts a message handed over in order: `lost` says how many before it never came.
    fn accept(&mut self, input: &str, meta: &Meta) -> eyre::Result<Accepted> {
        let Some(state) = self.streams.get_mut(input) else {
            eyre::bail!("input `{input}` is not read by this node");
        };
        if let Some(count) = is_end_of_stream(meta) {
            let lost = state.seq.end(count);
            state.ended = true;
            if meta.flag(CUT) {
                tracing::error!(input, "the stream was cut short: a node upstream failed");
                state.broken = true;
            }
            if lost > 0 {
                tracing::error!(input, lost, "messages lost at the end of the stream");
            }
            return Ok(Accepted::End(count));
        }
        let seq = meta
            .uint("message", SEQ)
            .map_err(|e| eyre::eyre!("input `{input}`: {e}"))?;
        let lost = match state.seq.observe(seq) {
            SeqStatus::InOrder => 0,
            SeqStatus::Gap { missing } => {
                tracing::error!(input, seq, missing, "messages lost before this one");
                missing
            }
            SeqStatus::Stale => {
                tracing::warn!(input, seq, "stale message");
                0
            }
            SeqStatus::Anomaly { jump } => {
                tracing::warn!(
                    input,
                    seq,
                    jump,
                    "a sequence number far past the stream's: refused"
                );
                return Ok(Accepted::Refused);
            }
            SeqStatus::Resynced { jump } => {
                tracing::warn!(input, seq, jump, "the stream was renumbered");
                0
            }
            SeqStatus::Restarted { expected } => {
                tracing::warn!(input, seq, expected, "the stream's sender restarted");
                0
            }
        };
        // The credits of messages lost on the way: a gap in the sender's count of what it sent
        // (messages never made, a gap in `seq` alone, took none). A sender that does not count
        // (not neuspike's runtime) has its `seq` gaps taken as lost on the way.
        let on_the_way = match meta.get(LINK_N) {
            Some(neuspike_schemas::Parameter::Integer(n)) if *n >= 0 => {
                let n = *n as u64;
                let gap = n.saturating_sub(state.next_link_n);
                state.next_link_n = state.next_link_n.max(n + 1);
                gap
            }
            _ => lost,
        };
        Ok(Accepted::Message { on_the_way })
    }
}

enum Accepted {
    /// A message, after `on_the_way` that its sender sent and never came.
    Message {
        on_the_way: u64,
    },
    End(u64),
    /// A message refused (its sequence number far past the stream's): not handed on, its
    /// credit returned.
    Refused,
}

/// Hands `on` the end of `input` (after `count` messages), then returns the credits still owed.
fn end_input(
    link: &mut Link,
    input: &str,
    count: u64,
    on: &mut impl FnMut(&mut Link, Received<'_>) -> eyre::Result<Flow>,
) -> eyre::Result<Flow> {
    let flow = on(link, Received::End { input, count })?;
    link.ended(input)?;
    Ok(flow)
}

/// The receive loop: hands every message and end-of-stream marker of the inputs in `inputs` to
/// `on`, with the node's [`Link`] to send on, in sequence order per input, until every input has
/// ended or `on` returns [`Flow::Stop`].
///
/// - A message that arrives before its turn waits for the ones before it (dora may deliver an
///   output's messages out of order, see [`crate::reorder`]); a missing one is given up after a
///   wait and counted as lost, and a message that comes after its turn is dropped and logged.
///   The wait counts only while dora has nothing queued for the node: a node busy computing
///   never gives up on messages that have come meanwhile.
/// - Sequence gaps are logged and counted in `inputs`; messages of inputs the node does not read
///   are logged and skipped; credits go back once `on` has taken a message; messages dora
///   dropped are logged.
/// - dora's `InputClosed`/`Stop` never end the loop (an input ends on its marker), only the end
///   of the event stream does; what is still held is handed over then, and an input still open is
///   logged.
///
/// # Errors
/// A message without a sequence number (named by its input), the first error of `on`, or credits
/// that could not be returned.
pub fn receive(
    link: &mut Link,
    inputs: &mut Inputs,
    mut on: impl FnMut(&mut Link, Received<'_>) -> eyre::Result<Flow>,
) -> eyre::Result<()> {
    if inputs.streams.is_empty() {
        return Ok(());
    }
    let mut flush = false;
    // The last instant dora had nothing more for this node. A held message waits for the ones
    // before it on this clock: time the node spends computing does not count, so a message
    // still queued in dora is not given up while the node was busy.
    let mut idle_at = Instant::now();
    loop {
        while let Some((input, (meta, data))) = inputs.next_due(idle_at, flush) {
            let flow = match inputs.accept(&input, &meta)? {
                Accepted::End(count) => {
                    if inputs.get(&input).is_some_and(|s| s.broken) {
                        link.mark_cut();
                    }
                    end_input(link, &input, count, &mut on)?
                }
                Accepted::Refused => {
                    link.taken(&input, 0)?;
                    Flow::Continue
                }
                Accepted::Message { on_the_way } => {
                    link.saw(&meta);
                    let flow = on(
                        link,
                        Received::Message {
                            input: &input,
                            meta: &meta,
                            data: &data,
                        },
                    )?;
                    link.taken(&input, on_the_way)?;
                    flow
                }
            };
            if flow == Flow::Stop || inputs.all_ended() {
                link.log_drops();
                return Ok(());
            }
        }
        if flush {
            break;
        }
        // An input whose sender failed ends as if its marker had come: the node finishes.
        for (input, count) in inputs.expire(Instant::now()) {
            link.mark_cut();
            let flow = end_input(link, &input, count, &mut on)?;
            if flow == Flow::Stop || inputs.all_ended() {
                link.log_drops();
                return Ok(());
            }
        }
        // Nobody is left to take what this node makes: it stops (the node that failed is
        // reported by the runner; this one ends cleanly).
        if link.consumers_gone() {
            tracing::warn!("every node this one feeds has ended before it: stopping");
            link.log_drops();
            return Ok(());
        }
        link.greet_restarted(Instant::now())?;
        let deadline = match (inputs.deadline(), link.next_greeting()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let polled = match deadline {
            Some(deadline) => link.next_event_until(deadline)?,
            None => link.next_event()?.map_or(Polled::Ended, Polled::Event),
        };
        match polled {
            Polled::Event(Event::Input { id, metadata, data }) => {
                link.heard_on(id.as_ref());
                let meta = meta_from_dora(&metadata.parameters);
                inputs.arrive(id.as_ref(), meta, data.as_array().clone(), Instant::now())?;
                link.log_drops();
            }
            Polled::Event(Event::InputClosed { id }) => {
                tracing::debug!(input = %id, "input closed");
                inputs.close(id.as_ref(), Instant::now());
            }
            Polled::Event(Event::NodeRestarted { id }) => {
                tracing::warn!(
                    node = %id,
                    "a producer was restarted: its stream goes on, what it missed is counted as a gap"
                );
                for input in link.producer_restarted(id.as_ref())? {
                    inputs.reopen(&input);
                }
            }
            Polled::Event(Event::Stop(cause)) => {
                tracing::debug!(?cause, "stop received; draining the inputs")
            }
            Polled::Timeout => idle_at = Instant::now(),
            Polled::Event(_) => {}
            Polled::Ended => flush = true,
        }
    }
    link.log_drops();
    for (id, s) in inputs.iter() {
        if !s.ended {
            tracing::error!(input = id, "input ended without its end-of-stream marker");
        }
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::testing::CannedInputs;
    use neuspike_schemas::{Frame, FrameKind, Message};
    use std::time::Duration;

    pub(crate) fn frame(seq: u64) -> Frame {
        Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: seq as i64,
            compute_ns: 0,
            chosen: None,
            budget_ns: None,
            seq,
            data: ndarray::Array2::zeros((1, 2)),
        }
    }

    #[test]
    fn a_stream_cut_upstream_cuts_the_streams_this_node_makes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        c.message("a", &frame(0)).expect("a0");
        let (mut meta, data) = neuspike_schemas::end_of_stream::<Frame>(1);
        meta.insert(CUT.to_string(), neuspike_schemas::Parameter::Bool(true));
        c.raw("a", meta, data).expect("cut marker");
        let mut inputs = Inputs::new(["a"]);
        let mut cut = false;
        let sent = c
            .run(|node, events| {
                let mut link = Link::new(node, events)?;
                link.declare::<Frame>("f");
                receive(&mut link, &mut inputs, |link, msg| {
                    if let Received::Message { meta, data, .. } = msg {
                        link.send("f", &Frame::from_arrow(meta, data)?)?;
                    }
                    Ok(Flow::Continue)
                })?;
                cut = link.is_cut();
                link.end_all()
            })
            .expect("run");
        let a = inputs.get("a").expect("a");
        assert!(a.ended && a.broken);
        assert_eq!(crate::testing::output_ids(&sent), ["f", "f"]);
        assert!(cut, "the node's own marker is flagged cut");
    }

    #[test]
    fn gaps_tails_and_foreign_inputs_are_accounted_and_the_markers_end_the_loop() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        c.message("a", &frame(0)).expect("a0");
        c.message("c", &frame(0)).expect("c0"); // not read by the node
        c.message("a", &frame(2)).expect("a2"); // a1 lost
        c.closed("b"); // dora may say so before b's last message
        c.message("b", &frame(0)).expect("b0");
        c.end::<Frame>("b", 1).expect("b end");
        c.end::<Frame>("a", 4).expect("a end"); // a3 lost at the tail
        c.message("a", &frame(9)).expect("after the end"); // never handed over
        let mut seen = Vec::new();
        let mut inputs = Inputs::new(["a", "b"]);
        c.run(|node, events| {
            let mut link = Link::new(node, events)?;
            receive(&mut link, &mut inputs, |_, msg| {
                seen.push(match msg {
                    Received::Message { input, meta, data } => {
                        let f = Frame::from_arrow(meta, data)?;
                        format!("{input}{}", f.seq)
                    }
                    Received::End { input, count } => format!("{input} end {count}"),
                });
                Ok(Flow::Continue)
            })
        })
        .expect("run");
        // a2 waits for a1, which never comes: it is handed over when the stream ends.
        assert_eq!(seen, ["a0", "b0", "b end 1", "a2", "a end 4"]);
        let a = inputs.get("a").expect("a");
        assert_eq!((a.seq.received(), a.seq.missing(), a.ended), (2, 2, true));
        assert_eq!((inputs.missing(), inputs.announced()), (2, 4));
        assert!(inputs.all_ended() && inputs.get("c").is_none());
    }

    #[test]
    fn messages_out_of_order_are_handed_over_in_order_and_a_late_one_is_dropped() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        for seq in [2, 0, 1, 1, 4, 3] {
            c.message("a", &frame(seq)).expect("a");
        }
        c.end::<Frame>("a", 5).expect("a end");
        let mut seen = Vec::new();
        let mut inputs = Inputs::new(["a"]);
        c.run(|node, events| {
            let mut link = Link::new(node, events)?;
            receive(&mut link, &mut inputs, |_, msg| {
                if let Received::Message { meta, data, .. } = msg {
                    seen.push(Frame::from_arrow(meta, data)?.seq);
                }
                Ok(Flow::Continue)
            })
        })
        .expect("run");
        assert_eq!(seen, [0, 1, 2, 3, 4]);
        let a = inputs.get("a").expect("a");
        assert_eq!(
            (a.seq.received(), a.seq.missing(), a.seq.stale(), a.ended),
            (5, 0, 1, true)
        );
    }

    /// A message held for the ones before it does not give up on them while the node computes:
    /// message 2 comes first and waits; message 0 takes longer than the reorder's wait, and 1,
    /// queued meanwhile, is still taken in its turn.
    #[test]
    fn a_slow_message_does_not_make_the_held_ones_give_up_on_what_is_queued() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        for seq in [2, 0, 1, 3] {
            c.message("a", &frame(seq)).expect("a");
        }
        c.end::<Frame>("a", 4).expect("a end");
        let mut seen = Vec::new();
        let mut inputs = Inputs::new(["a"]);
        c.run(|node, events| {
            let mut link = Link::new(node, events)?;
            receive(&mut link, &mut inputs, |_, msg| {
                if let Received::Message { meta, data, .. } = msg {
                    let seq = Frame::from_arrow(meta, data)?.seq;
                    if seq == 0 {
                        std::thread::sleep(crate::reorder::MAX_WAIT + Duration::from_millis(200));
                    }
                    seen.push(seq);
                }
                Ok(Flow::Continue)
            })
        })
        .expect("run");
        assert_eq!(seen, [0, 1, 2, 3]);
        let a = inputs.get("a").expect("a");
        assert_eq!((a.seq.received(), a.seq.missing()), (4, 0));
    }

    #[test]
    fn a_message_without_a_sequence_number_is_an_error_naming_the_input() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        let (mut meta, data) = frame(0).to_arrow();
        meta.remove(SEQ);
        c.raw("a", meta, data).expect("raw");
        let mut inputs = Inputs::new(["a"]);
        let e = c
            .run(|node, events| {
                let mut link = Link::new(node, events)?;
                receive(&mut link, &mut inputs, |_, _| Ok(Flow::Continue))
            })
            .expect_err("refused")
            .to_string();
        assert!(e.contains("input `a`") && e.contains("seq"), "{e}");
    }
}
