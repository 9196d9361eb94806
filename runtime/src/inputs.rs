//! The receive loop: every input's sequence numbers and end-of-stream marker, accounted once.

use std::collections::BTreeMap;

use dora_node_api::{Event, EventStream};
use neuspike_schemas::arrow::array::ArrayRef;
use neuspike_schemas::meta::SEQ;
use neuspike_schemas::{Meta, MetaExt, SeqStatus, SeqTracker, is_end_of_stream};

use crate::metadata::meta_from_dora;

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

/// Whether the receive loop goes on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Take the next message.
    Continue,
    /// The node has all it needs: leave the loop.
    Stop,
}

/// One input's stream: its sequence numbers and whether its end-of-stream marker came.
#[derive(Clone, Debug, Default)]
pub struct InputState {
    /// The input's sequence numbers: received, missing, stale, announced.
    pub seq: SeqTracker,
    /// Whether the end-of-stream marker arrived.
    pub ended: bool,
}

/// The inputs a node reads, and the state of each.
#[derive(Clone, Debug, Default)]
pub struct Inputs {
    streams: BTreeMap<String, InputState>,
}

impl Inputs {
    /// The inputs `ids` (the node's declared inputs, or those its method reads). Messages on any
    /// other input are logged and ignored.
    pub fn new<S: AsRef<str>>(ids: impl IntoIterator<Item = S>) -> Self {
        Inputs {
            streams: ids
                .into_iter()
                .map(|id| (id.as_ref().to_string(), InputState::default()))
                .collect(),
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
    fn accept(&mut self, input: &str, meta: &Meta) -> eyre::Result<Option<Accepted>> {
        let Some(state) = self.streams.get_mut(input) else {
            return Ok(None);
        };
        if let Some(count) = is_end_of_stream(meta) {
            let lost = state.seq.end(count);
            state.ended = true;
            if lost > 0 {
                tracing::error!(input, lost, "messages lost at the end of the stream");
            }
            return Ok(Some(Accepted::End(count)));
        }
        let seq = meta
            .uint("message", SEQ)
            .map_err(|e| eyre::eyre!("input `{input}`: {e}"))?;
        match state.seq.observe(seq) {
            SeqStatus::InOrder => {}
            SeqStatus::Gap { missing } => {
                tracing::error!(input, seq, missing, "messages lost before this one")
            }
            SeqStatus::Stale => tracing::warn!(input, seq, "stale message"),
        }
        Ok(Some(Accepted::Message))
    }
}

enum Accepted {
    Message,
    End(u64),
}

/// Runs the receive loop: hands `on` every message and end-of-stream marker of the node's
/// `inputs`, in the order they come, until every input has ended, `on` returns [`Flow::Stop`], or
/// dora closes the stream. `InputClosed` and `Stop` never end it: dora's scheduler may deliver
/// them before an input's last messages (the tail of a run was lost that way), so only the
/// end-of-stream markers, or the end of the event stream, do.
pub fn receive(
    events: &mut EventStream,
    inputs: &mut Inputs,
    mut on: impl FnMut(Received<'_>) -> eyre::Result<Flow>,
) -> eyre::Result<()> {
    if inputs.streams.is_empty() {
        return Ok(());
    }
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } => {
                let input: &str = id.as_ref();
                let meta = meta_from_dora(&metadata.parameters);
                let flow = match inputs.accept(input, &meta)? {
                    None => {
                        tracing::warn!(input, "input not read by this node: ignored");
                        Flow::Continue
                    }
                    Some(Accepted::End(count)) => on(Received::End { input, count })?,
                    Some(Accepted::Message) => on(Received::Message {
                        input,
                        meta: &meta,
                        data: data.as_array(),
                    })?,
                };
                if flow == Flow::Stop {
                    return Ok(());
                }
                if inputs.all_ended() {
                    break;
                }
            }
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the inputs"),
            _ => {}
        }
    }
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

    pub(crate) fn frame(seq: u64) -> Frame {
        Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: seq as i64,
            compute_ns: 0,
            seq,
            data: ndarray::Array2::zeros((1, 2)),
        }
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
        c.run(|_node, mut events| {
            receive(&mut events, &mut inputs, |msg| {
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
        assert_eq!(seen, ["a0", "a2", "b0", "b end 1", "a end 4"]);
        let a = inputs.get("a").expect("a");
        assert_eq!((a.seq.received(), a.seq.missing(), a.ended), (2, 2, true));
        assert_eq!((inputs.missing(), inputs.announced()), (2, 4));
        assert!(inputs.all_ended() && inputs.get("c").is_none());
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
            .run(|_node, mut events| receive(&mut events, &mut inputs, |_| Ok(Flow::Continue)))
            .expect_err("refused")
            .to_string();
        assert!(e.contains("input `a`") && e.contains("seq"), "{e}");
    }
}
