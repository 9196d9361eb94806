//! A node's outputs: declared with their message type, sent with their sequence numbers
//! followed, and ended with the count their receivers check.

use dora_node_api::dora_core::config::DataId;
use dora_node_api::{DoraArray, DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_schemas::arrow::array::new_empty_array;
use neuspike_schemas::arrow::datatypes::DataType;
use neuspike_schemas::meta::SEQ;
use neuspike_schemas::{Message, MetaExt, end_of_stream_header};

use crate::metadata::meta_to_dora;
use crate::{Flow, stop_requested};

struct Output {
    id: DataId,
    data_type: DataType,
    /// One past the highest sequence number sent (or the floor set by [`Outputs::at_least`]).
    count: u64,
    ended: bool,
}

/// The outputs of a node. Each is declared once with its message type ([`Outputs::declare`]);
/// [`Outputs::end_all`] then ends every one with the count of messages its sequence numbers
/// cover, so a receiver can tell a message lost anywhere, the tail included.
pub struct Outputs {
    node: DoraNode,
    outputs: Vec<Output>,
}

impl Outputs {
    /// The outputs of `node`, none declared yet.
    pub fn new(node: DoraNode) -> Self {
        Outputs {
            node,
            outputs: Vec::new(),
        }
    }

    /// The dora node (its configuration: the graph's inputs and outputs).
    pub fn node(&self) -> &DoraNode {
        &self.node
    }

    /// Declares output `id`, carrying messages of type `M`.
    pub fn declare<M: Message>(&mut self, id: &str) -> &mut Self {
        if !self
            .outputs
            .iter()
            .any(|o| AsRef::<str>::as_ref(&o.id) == id)
        {
            self.outputs.push(Output {
                id: DataId::from(id.to_string()),
                data_type: M::data_type(),
                count: 0,
                ended: false,
            });
        }
        self
    }

    /// Whether output `id` is declared.
    pub fn declared(&self, id: &str) -> bool {
        self.outputs
            .iter()
            .any(|o| AsRef::<str>::as_ref(&o.id) == id)
    }

    fn output(&mut self, id: &str) -> eyre::Result<&mut Output> {
        self.outputs
            .iter_mut()
            .find(|o| AsRef::<str>::as_ref(&o.id) == id)
            .ok_or_else(|| eyre::eyre!("output `{id}` was never declared by this node"))
    }

    /// Sends `msg` on output `id`.
    pub fn send<M: Message>(&mut self, id: &str, msg: &M) -> eyre::Result<()> {
        let (meta, data) = msg.to_arrow();
        let seq = meta
            .uint("message", SEQ)
            .map_err(|e| eyre::eyre!("output `{id}`: {e}"))?;
        let out = self.output(id)?;
        if out.ended {
            eyre::bail!("output `{id}` was sent a message after its end-of-stream marker");
        }
        out.count = out.count.max(seq.saturating_add(1));
        let dora_id = out.id.clone();
        self.node
            .send_output(dora_id, meta_to_dora(&meta), DoraArray::from(data))
            .wrap_err_with(|| format!("failed to send on output `{id}`"))
    }

    /// Makes output `id` announce at least `count` messages at its end: a node whose input lost
    /// the last messages passes the sender's count on, so the loss shows downstream too.
    pub fn at_least(&mut self, id: &str, count: u64) -> eyre::Result<()> {
        let out = self.output(id)?;
        out.count = out.count.max(count);
        Ok(())
    }

    /// The count output `id` announces at its end so far.
    pub fn count(&self, id: &str) -> u64 {
        self.outputs
            .iter()
            .find(|o| AsRef::<str>::as_ref(&o.id) == id)
            .map_or(0, |o| o.count)
    }

    /// Ends every declared output not yet ended with its end-of-stream marker. Every output is
    /// tried even when one fails; the first failure is returned.
    pub fn end_all(&mut self) -> eyre::Result<()> {
        let mut first_err = None;
        for out in self.outputs.iter_mut().filter(|o| !o.ended) {
            out.ended = true;
            let meta = end_of_stream_header(out.count);
            let data = new_empty_array(&out.data_type);
            if let Err(e) =
                self.node
                    .send_output(out.id.clone(), meta_to_dora(&meta), DoraArray::from(data))
            {
                tracing::error!(output = %out.id, "could not send the end-of-stream marker: {e}");
                first_err.get_or_insert(eyre::eyre!("failed to end output `{}`: {e}", out.id));
            }
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// Runs a source: calls `step` (which sends the next messages on `outputs`) until it returns
/// [`Flow::Stop`] or a stop is requested, then ends every output, whatever happened: after an
/// error the messages already sent still form whole streams, and the error is returned after.
pub fn produce(
    outputs: &mut Outputs,
    events: &mut EventStream,
    mut step: impl FnMut(&mut Outputs) -> eyre::Result<Flow>,
) -> eyre::Result<()> {
    let result = loop {
        if stop_requested(events) {
            break Ok(());
        }
        match step(outputs) {
            Ok(Flow::Continue) => {}
            Ok(Flow::Stop) => break Ok(()),
            Err(e) => break Err(e),
        }
    };
    let ended = outputs.end_all();
    result.and(ended)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inputs::tests::frame;
    use crate::testing::{CannedInputs, output_ids, payload_len};
    use neuspike_schemas::Frame;

    #[test]
    fn outputs_count_by_sequence_number_and_end_once() {
        let dir = tempfile::tempdir().expect("tempdir");
        let sent = CannedInputs::new(dir.path())
            .run(|node, _events| {
                let mut out = Outputs::new(node);
                out.declare::<Frame>("f");
                out.send("f", &frame(0))?;
                out.send("f", &frame(2))?; // 1 was never made: the count still covers it
                assert_eq!(out.count("f"), 3);
                out.at_least("f", 5)?;
                assert_eq!(out.count("f"), 5);
                assert!(out.send("g", &frame(0)).is_err(), "undeclared output");
                out.end_all()?;
                let e = out
                    .send("f", &frame(3))
                    .expect_err("after the end")
                    .to_string();
                assert!(e.contains("after its end-of-stream marker"), "{e}");
                out.end_all() // nothing left to end
            })
            .expect("run");
        assert_eq!(output_ids(&sent), ["f", "f", "f"]);
        assert_eq!(payload_len(&sent[2]), 0, "the end-of-stream marker");
    }

    #[test]
    fn a_source_that_fails_still_ends_its_outputs() {
        let dir = tempfile::tempdir().expect("tempdir");
        let sent = CannedInputs::new(dir.path())
            .run(|node, mut events| {
                let mut out = Outputs::new(node);
                out.declare::<Frame>("f");
                let mut n = 0;
                let r = produce(&mut out, &mut events, |out| {
                    n += 1;
                    if n == 3 {
                        eyre::bail!("the recording broke");
                    }
                    out.send("f", &frame(n - 1))?;
                    Ok(Flow::Continue)
                });
                let e = r.expect_err("the step's error").to_string();
                assert!(e.contains("recording broke"), "{e}");
                assert_eq!(out.count("f"), 2);
                Ok(())
            })
            .expect("run");
        assert_eq!(output_ids(&sent), ["f", "f", "f"]);
        assert_eq!(payload_len(&sent[2]), 0, "ended after the error");
    }
}
