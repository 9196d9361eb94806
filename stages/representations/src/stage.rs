//! Represent as a stage: aligned windows in, one output per representation kind asked for.

use neuspike_schemas::{AlignedWindow, RepresentationKind};
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Port, Stage, Tallies};

use crate::Representer;

/// The input of windows.
pub const WINDOWS: &str = "windows";

/// The represent stage: input `windows`; one output per kind in `kinds`, named as the kind
/// (`tfp`, `isi`, ...). Sequence numbers follow the windows', so a lost window shows downstream.
///
/// `stp` (TFSTP's rate) is the one with state across windows: each pixel's synapse is fed every
/// plane once, up to each window's reference plane.
#[derive(Debug)]
pub struct RepresentStage {
    representer: Representer,
    kinds: Vec<RepresentationKind>,
    windows: u64,
}

impl RepresentStage {
    /// The stage computing `kinds` with `representer`.
    pub fn new(representer: Representer, kinds: &[RepresentationKind]) -> Self {
        RepresentStage {
            representer,
            kinds: kinds.to_vec(),
            windows: 0,
        }
    }

    /// The kinds it computes.
    pub fn kinds(&self) -> &[RepresentationKind] {
        &self.kinds
    }
}

impl Stage for RepresentStage {
    fn name(&self) -> &str {
        "represent"
    }

    fn inputs(&self) -> Vec<Port> {
        vec![Port::new(WINDOWS, MsgType::AlignedWindow)]
    }

    fn outputs(&self) -> Vec<Port> {
        self.kinds
            .iter()
            .map(|k| Port::new(k.name(), MsgType::Representation))
            .collect()
    }

    fn on_message(&mut self, _input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        let w = AlignedWindow::try_from(msg)?;
        self.windows += 1;
        for &kind in &self.kinds {
            let r = self
                .representer
                .represent(kind, &w)
                .map_err(|e| eyre::eyre!("represent: window {} ({kind}): {e}", w.seq()))?;
            out.send(kind.name(), r);
        }
        Ok(Flow::Continue)
    }

    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        // A window lost at the tail shows downstream too.
        let announced = inputs.announced();
        for k in &self.kinds {
            out.at_least(k.name(), announced);
        }
        tracing::info!(
            windows = self.windows,
            lost = inputs.missing(),
            "represent finished"
        );
        Ok(())
    }
}
