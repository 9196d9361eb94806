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

    /// One frame of `input`: written, scored and counted.
    fn take(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
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
        let r = self.take(input, msg, out);
        if let (Err(e), Some(sink)) = (&r, self.sink.as_mut()) {
            // The summary written at the finish says why the frames stop there.
            sink.note_failure(&format!("{e:#}"));
        }
        r
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BitDepth;
    use neuspike_schemas::FrameKind;
    use neuspike_stage::Tally;

    fn frame(seq: u64) -> Msg {
        Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: seq as i64,
            compute_ns: 1,
            chosen: None,
            budget_ns: None,
            seq,
            data: ndarray::Array2::from_elem((4, 5), 0.5),
        }
        .into()
    }

    fn stage(out: &std::path::Path) -> SinkStage {
        let cfg = SinkConfig {
            out: out.to_path_buf(),
            bit_depth: BitDepth::Eight,
            write_ground_truth: false,
            truth_within_ns: 0,
            write_every: 1,
            score_every: 1,
            delay_us: 0,
        };
        SinkStage::new(&cfg, &["tfp".to_string()]).expect("sink")
    }

    fn tallies(received: u64) -> Tallies {
        Tallies(vec![(
            "tfp".into(),
            Tally {
                announced: Some(3),
                received,
                ended: true,
                ..Tally::default()
            },
        )])
    }

    #[test]
    fn when_a_frame_cannot_be_written_the_summary_still_gives_the_counts_and_the_failure() {
        let dir = tempfile::tempdir().expect("tempdir");
        // The folder of the method's PNGs is a file: the first frame cannot be written.
        std::fs::write(dir.path().join("tfp"), "in the way").expect("write");
        let mut s = stage(dir.path());
        let mut out = Outbox::new();
        let e = format!("{:#}", s.on_message("tfp", frame(0), &mut out).unwrap_err());
        assert!(e.contains("tfp"), "{e}");
        s.finish(&tallies(1), &mut out).expect("the summary fits");
        let md = std::fs::read_to_string(dir.path().join("summary.md")).expect("summary");
        assert!(md.contains("**The sink failed**"), "{md}");
        assert!(md.contains("| tfp |"), "{md}");
    }

    #[test]
    fn when_the_summary_cannot_be_written_its_counts_come_with_the_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = stage(dir.path());
        let mut out = Outbox::new();
        s.on_message("tfp", frame(0), &mut out).expect("frame 0");
        s.on_message("tfp", frame(1), &mut out).expect("frame 1");
        // A folder where the summary goes: the rename over it fails.
        std::fs::create_dir(dir.path().join("summary.md")).expect("mkdir");
        std::fs::write(dir.path().join("summary.md").join("x"), "x").expect("write");
        let e = s.finish(&tallies(2), &mut out).unwrap_err().to_string();
        assert!(!e.contains('\n'), "one line: {e}");
        assert!(
            e.contains("cannot write the summary")
                && e.contains("tfp: 3 expected, 2 received, 2 written, 0 missing"),
            "{e}"
        );
    }
}
