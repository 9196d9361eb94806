//! A source that replays messages already made: a recording held in memory, a sample built by
//! hand, a test's canned stream.

use crate::{Flow, Msg, MsgType, Outbox, Port, Stage};

/// One output of a [`Replay`]: its port and the messages still to send.
struct Output<'a> {
    port: Port,
    msgs: Box<dyn Iterator<Item = Msg> + Send + 'a>,
    done: bool,
}

/// A source stage that sends the messages of each of its outputs in the order given, one
/// message of each output a step (the outputs interleaved, so that a stage reading two of them
/// gets both streams together), and stops when every output has sent all of its own.
///
/// The messages come from iterators, so a long stream is made as it is sent, not held whole.
pub struct Replay<'a> {
    name: String,
    outputs: Vec<Output<'a>>,
}

impl std::fmt::Debug for Replay<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Replay")
            .field("name", &self.name)
            .field(
                "outputs",
                &self.outputs.iter().map(|o| &o.port.id).collect::<Vec<_>>(),
            )
            .finish()
    }
}

impl<'a> Replay<'a> {
    /// A replay named `name` (its name in logs and errors), without outputs yet.
    pub fn new(name: &str) -> Self {
        Replay {
            name: name.to_string(),
            outputs: Vec::new(),
        }
    }

    /// Adds output `id`, of messages of type `ty`, sending `msgs` in order. A message of another
    /// type fails the run (the chain checks every message against its port).
    pub fn output(
        mut self,
        id: &str,
        ty: MsgType,
        msgs: impl IntoIterator<Item = Msg, IntoIter: Send + 'a>,
    ) -> Self {
        self.outputs.push(Output {
            port: Port::new(id, ty),
            msgs: Box::new(msgs.into_iter()),
            done: false,
        });
        self
    }
}

impl Stage for Replay<'_> {
    fn name(&self) -> &str {
        &self.name
    }

    fn inputs(&self) -> Vec<Port> {
        Vec::new()
    }

    fn outputs(&self) -> Vec<Port> {
        self.outputs.iter().map(|o| o.port.clone()).collect()
    }

    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        for o in self.outputs.iter_mut().filter(|o| !o.done) {
            match o.msgs.next() {
                Some(msg) => out.send(&o.port.id, msg),
                None => o.done = true,
            }
        }
        Ok(if self.outputs.iter().all(|o| o.done) {
            Flow::Stop
        } else {
            Flow::Continue
        })
    }

    fn on_message(&mut self, _input: &str, _msg: Msg, _out: &mut Outbox) -> eyre::Result<Flow> {
        Ok(Flow::Continue)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Chain;
    use neuspike_schemas::{Frame, FrameKind};
    use std::sync::Mutex;

    fn frame(seq: u64) -> Msg {
        Frame {
            kind: FrameKind::Reconstruction,
            method: "replay".into(),
            t_ref_ns: seq as i64,
            compute_ns: 0,
            chosen: None,
            budget_ns: None,
            seq,
            data: ndarray::Array2::zeros((1, 1)),
        }
        .into()
    }

    #[test]
    fn every_message_goes_out_in_order_and_the_stream_ends_with_its_count() {
        let got = Mutex::new(Vec::new());
        let mut chain = Chain::new();
        chain
            .add(
                "replay",
                Replay::new("replay").output("frames", MsgType::Frame, (0..5).map(frame)),
            )
            .unwrap();
        chain
            .tap("replay/frames", |m| {
                got.lock().unwrap().push(m.seq());
                Ok(())
            })
            .unwrap();
        let report = chain.run().unwrap();
        assert_eq!(*got.lock().unwrap(), vec![0, 1, 2, 3, 4]);
        assert_eq!(report.stage("replay").unwrap().sent, 5);
    }

    #[test]
    fn a_message_of_the_wrong_type_fails_the_run() {
        let mut chain = Chain::new();
        chain
            .add(
                "replay",
                Replay::new("replay").output("spikes", MsgType::SpikeChunk, [frame(0)]),
            )
            .unwrap();
        chain.tap("replay/spikes", |_| Ok(())).unwrap();
        let e = format!("{:#}", chain.run().unwrap_err());
        assert!(e.contains("replay") && e.contains("output `spikes`"), "{e}");
    }
}
