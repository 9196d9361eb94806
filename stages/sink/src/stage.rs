//! The sink as a stage: frames in (ground truth among them), PNGs, metrics and the summary out
//! to files.

use neuspike_schemas::Frame;
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Port, Stage, Tallies, unix_now_ns};

use crate::{GROUND_TRUTH, InputTally, Sink, SinkConfig, SinkError};

/// The sink stage: inputs `ground_truth` (optional) and one per method, no outputs. Frames are
/// written and scored against the nearest ground truth as they come; `summary.md` is written at
/// the end, with the tallies of every input.
pub struct SinkStage {
    sink: Option<Sink>,
    inputs: Vec<String>,
    summary: Option<std::path::PathBuf>,
}

impl SinkStage {
    /// A sink under `cfg.out` (created) reading `inputs`.
    ///
    /// # Errors
    /// The folder or the metrics file could not be made.
    pub fn new(cfg: &SinkConfig, inputs: &[String]) -> Result<Self, SinkError> {
        let has_gt = inputs.iter().any(|i| i == GROUND_TRUTH);
        Ok(SinkStage {
            sink: Some(Sink::new(cfg, has_gt)?),
            inputs: inputs.to_vec(),
            summary: None,
        })
    }

    /// The summary's path, once written.
    pub fn summary(&self) -> Option<&std::path::Path> {
        self.summary.as_deref()
    }

    fn sink(&mut self) -> eyre::Result<&mut Sink> {
        self.sink
            .as_mut()
            .ok_or_else(|| eyre::eyre!("sink: a frame after the summary was written"))
    }
}

impl Stage for SinkStage {
    fn name(&self) -> &str {
        "sink"
    }

    fn inputs(&self) -> Vec<Port> {
        self.inputs
            .iter()
            .map(|i| Port::new(i.as_str(), MsgType::Frame))
            .collect()
    }

    fn outputs(&self) -> Vec<Port> {
        vec![]
    }

    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        let f = Frame::try_from(msg).map_err(|e| eyre::eyre!("sink: input `{input}`: {e}"))?;
        let origin = out.origin_unix_ns();
        let sink = self.sink()?;
        if input == GROUND_TRUTH {
            sink.on_truth(f)?;
        } else {
            if let Some(origin) = origin {
                let now = unix_now_ns();
                sink.on_latency(input, now.saturating_sub(origin), now);
            }
            sink.on_frame(input, f)?;
        }
        Ok(Flow::Continue)
    }

    fn on_end(&mut self, input: &str, _count: u64, _out: &mut Outbox) -> eyre::Result<Flow> {
        if input == GROUND_TRUTH {
            self.sink()?.truth_ended()?;
        }
        Ok(Flow::Continue)
    }

    fn finish(&mut self, inputs: &Tallies, _out: &mut Outbox) -> eyre::Result<()> {
        let Some(sink) = self.sink.take() else {
            return Ok(());
        };
        let tallies = inputs.iter().map(|(name, t)| {
            let tally = InputTally {
                announced: t.announced,
                received: t.received,
                missing: t.missing,
                ended: t.ended,
                cut: t.cut,
            };
            (name, tally)
        });
        let path = sink.finish(tallies)?;
        tracing::info!("summary written to {}", path.display());
        self.summary = Some(path);
        Ok(())
    }
}
