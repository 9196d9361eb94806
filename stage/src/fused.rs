//! Several stages as one: a [`Chain`] with inlets and outlets, run by any driver as a [`Stage`].
//!
//! The dora driver runs a fused stage as one node, one process: the messages between its stages
//! are handed over as Rust values (no Arrow, no daemon, no copies), and only its inlets and
//! outlets are dora links. The chain's rules hold inside (sequence numbers followed, every end
//! with its count, a failure cuts what is downstream), and each stage's time is still measured
//! ([`Fused::report`]).

use std::time::Instant;

use eyre::bail;

use crate::{Chain, ChainReport, Flow, Msg, Outbox, Port, Stage, Tallies, unix_now_ns};

/// A chain run as one stage. See the module's docs.
pub struct Fused {
    name: String,
    chain: Chain<'static>,
    inputs: Vec<Port>,
    outputs: Vec<Port>,
    started: Instant,
    report: Option<ChainReport>,
}

impl Chain<'static> {
    /// The chain as one stage named `name`: its inputs are the chain's inlets, its outputs its
    /// outlets. Its sources and sinks run on threads of their own ([`Chain::run_on_threads`])
    /// when it holds other stages.
    ///
    /// # Errors
    /// An input of a stage is fed by nothing, or the chain has a source and inlets both (a
    /// driver steps a stage without inputs, and feeds one with inputs: not both).
    pub fn into_stage(mut self, name: &str) -> eyre::Result<Fused> {
        self.check_fed()?;
        let inputs = self.inlet_ports();
        if self.has_source() && !inputs.is_empty() {
            bail!(
                "{name}: a fused stage with a source takes no input from outside (it has {})",
                inputs
                    .iter()
                    .map(|p| format!("`{}`", p.id))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        self.run_on_threads();
        Ok(Fused {
            name: name.to_string(),
            outputs: self.outlet_ports(),
            inputs,
            chain: self,
            started: Instant::now(),
            report: None,
        })
    }
}

impl Fused {
    /// What each stage did (after [`Stage::finish`]).
    pub fn report(&self) -> Option<&ChainReport> {
        self.report.as_ref()
    }

    /// Sends what the outlets sent, each with its origin stamp.
    fn export(&mut self, out: &mut Outbox) {
        let sent: Vec<_> = self.chain.take_exported().collect();
        for e in sent {
            out.set_origin(e.origin);
            out.send(self.chain.outlet_name(e.outlet), e.msg);
        }
    }

    fn flow(&self) -> Flow {
        if self.chain.all_done() {
            Flow::Stop
        } else {
            Flow::Continue
        }
    }
}

impl Stage for Fused {
    fn name(&self) -> &str {
        &self.name
    }

    fn inputs(&self) -> Vec<Port> {
        self.inputs.clone()
    }

    fn outputs(&self) -> Vec<Port> {
        self.outputs.clone()
    }

    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        let live = self.chain.step_sources();
        self.export(out);
        Ok(if live { Flow::Continue } else { Flow::Stop })
    }

    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        let origin = out.origin_unix_ns().unwrap_or_else(unix_now_ns);
        self.chain.push(input, msg, origin)?;
        self.export(out);
        Ok(self.flow())
    }

    fn on_end(&mut self, input: &str, count: u64, out: &mut Outbox) -> eyre::Result<Flow> {
        self.chain.push_end(input, count, false)?;
        self.export(out);
        Ok(self.flow())
    }

    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        self.chain.finish_rest();
        self.export(out);
        for (name, count) in self.chain.outlet_counts() {
            out.at_least(&name, count);
        }
        if inputs.cut() || self.chain.any_cut() {
            out.mark_cut();
        }
        let report = self.chain.report(self.started.elapsed());
        for s in &report.stages {
            tracing::debug!(
                fused = self.name,
                stage = s.id,
                busy_s = s.busy.as_secs_f64(),
                received = s.received,
                sent = s.sent,
                missing = s.inputs.missing(),
                "stage done"
            );
        }
        self.report = Some(report);
        match self.chain.take_error() {
            Some(e) => Err(e.wrap_err(format!("fused stage `{}`", self.name))),
            None => Ok(()),
        }
    }
}
