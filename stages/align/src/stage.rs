//! Align as a stage: spike chunks and event batches in, windows (and the event stream cut at
//! each window's reference instant) out.

use neuspike_schemas::{EventBatch, SpikeChunk};
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Port, Stage, Tallies};

use crate::{AlignConfig, Aligner};

/// Input and output ids.
pub const SPIKES: &str = "spikes";
/// The events input, and the output of the event stream cut at each window.
pub const EVENTS: &str = "events";
/// The windows output.
pub const WINDOWS: &str = "windows";

/// The align stage: an [`Aligner`] between its ports. Inputs `spikes` and, with events, `events`;
/// outputs `windows` and, when asked, `events` (each window followed by its batch of the stream).
#[derive(Debug)]
pub struct AlignStage {
    aligner: Aligner,
    with_events: bool,
}

impl AlignStage {
    /// The stage; `with_events` when an event stream comes in, `stream_events` to send the
    /// event stream cut at each window.
    pub fn new(cfg: AlignConfig, with_events: bool, stream_events: bool) -> Self {
        let mut aligner = Aligner::new(cfg, with_events);
        if stream_events {
            aligner = aligner.with_event_stream();
        }
        AlignStage {
            aligner,
            with_events,
        }
    }

    /// The aligner.
    pub fn aligner(&self) -> &Aligner {
        &self.aligner
    }

    /// Sends every ready window, each followed by its batch of the event stream (if wanted);
    /// [`Flow::Stop`] once nothing more can come.
    fn send_ready(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        if let Some(e) = self.aligner.take_rig_error() {
            return Err(e.into());
        }
        while let Some(window) = self.aligner.pop_ready() {
            out.send(WINDOWS, window);
            if let Some(batch) = self.aligner.pop_stream() {
                out.send(EVENTS, batch);
            }
        }
        Ok(if self.aligner.finished() {
            Flow::Stop
        } else {
            Flow::Continue
        })
    }
}

impl Stage for AlignStage {
    fn name(&self) -> &str {
        "align"
    }

    fn inputs(&self) -> Vec<Port> {
        let mut ports = vec![Port::new(SPIKES, MsgType::SpikeChunk)];
        if self.with_events {
            ports.push(Port::new(EVENTS, MsgType::EventBatch));
        }
        ports
    }

    fn outputs(&self) -> Vec<Port> {
        let mut ports = vec![Port::new(WINDOWS, MsgType::AlignedWindow)];
        if self.aligner.streams_events() {
            ports.push(Port::new(EVENTS, MsgType::EventBatch));
        }
        ports
    }

    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        if input == SPIKES {
            self.aligner.push_spikes(SpikeChunk::try_from(msg)?)?;
        } else {
            self.aligner.push_events(EventBatch::try_from(msg)?);
        }
        self.send_ready(out)
    }

    fn on_end(&mut self, input: &str, _count: u64, out: &mut Outbox) -> eyre::Result<Flow> {
        if input == SPIKES {
            self.aligner.close_spikes();
        } else {
            self.aligner.close_events();
        }
        self.send_ready(out)
    }

    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        self.aligner.close_spikes();
        self.aligner.close_events();
        self.send_ready(out)?;
        // Windows skipped for missing planes count as sent-and-lost: the ends cover them.
        out.at_least(WINDOWS, self.aligner.next_seq());
        if self.aligner.streams_events() {
            out.at_least(EVENTS, self.aligner.next_seq());
        }
        tracing::info!(
            windows = self.aligner.emitted(),
            skipped = self.aligner.skipped_windows(),
            spike_chunks_lost = inputs.get(SPIKES).map_or(0, |s| s.missing),
            event_batches_lost = inputs.get(EVENTS).map_or(0, |s| s.missing),
            events_outside_the_spike_grid = self.aligner.dropped_events(),
            spike_chunks_refused = self.aligner.refused_chunks(),
            "align finished"
        );
        Ok(())
    }
}
