//! Infer as a stage: the inputs its method reads in, frames out.

use neuspike_schemas::{AlignedWindow, EventBatch, Representation};
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Port, Stage, Tallies};

use crate::{EVENTS, Reconstructor, WINDOWS};

/// The output of frames.
pub const FRAMES: &str = "frames";

/// The infer stage: a [`Reconstructor`] between its ports. Inputs as the method reads them
/// ([`Reconstructor::input_ids`]: representations by kind, `events`, or `windows` for `auto`);
/// output `frames`. A window is reconstructed once all its inputs came, in order.
#[derive(Debug)]
pub struct InferStage {
    reconstructor: Reconstructor,
    /// One past the highest frame sequence number sent.
    count: u64,
}

impl InferStage {
    /// The stage of `reconstructor`.
    pub fn new(reconstructor: Reconstructor) -> Self {
        InferStage {
            reconstructor,
            count: 0,
        }
    }

    /// Its reconstructor.
    pub fn reconstructor(&self) -> &Reconstructor {
        &self.reconstructor
    }

    fn send_ready(&mut self, flush: bool, out: &mut Outbox) -> eyre::Result<()> {
        for frame in self
            .reconstructor
            .ready(flush)
            .map_err(|e| eyre::eyre!("infer: {e}"))?
        {
            self.count = self.count.max(frame.seq.saturating_add(1));
            out.send(FRAMES, frame);
        }
        Ok(())
    }
}

impl Stage for InferStage {
    fn name(&self) -> &str {
        "infer"
    }

    fn inputs(&self) -> Vec<Port> {
        self.reconstructor
            .input_ids()
            .into_iter()
            .map(|id| {
                let ty = match id {
                    EVENTS => MsgType::EventBatch,
                    WINDOWS => MsgType::AlignedWindow,
                    _ => MsgType::Representation,
                };
                Port::new(id, ty)
            })
            .collect()
    }

    fn outputs(&self) -> Vec<Port> {
        vec![Port::new(FRAMES, MsgType::Frame)]
    }

    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        match input {
            EVENTS => self.reconstructor.push_events(EventBatch::try_from(msg)?),
            WINDOWS => self
                .reconstructor
                .push_window(AlignedWindow::try_from(msg)?),
            _ => self
                .reconstructor
                .push_representation(input, Representation::try_from(msg)?),
        }
        self.send_ready(false, out)?;
        Ok(Flow::Continue)
    }

    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        self.send_ready(true, out)?;
        // Windows lost upstream at the tail show downstream too.
        let announced = inputs.announced();
        out.at_least(FRAMES, announced);
        self.reconstructor
            .log_end(self.count.max(announced), inputs.missing());
        Ok(())
    }
}
