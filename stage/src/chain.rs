//! The in-process driver: stages in one process, wired output to input, run without dora.
//!
//! A [`Chain`] holds stages under ids and the edges between their ports (`align/windows` ->
//! `represent/windows`), checked when they are made: both ends exist and carry one type, and an
//! input has one sender. [`Chain::run`] steps the sources in turn and hands every message on at
//! once, in the order it was sent, to every consumer of its output (moved to the last one, cloned
//! for the others); a [`Chain::tap`] receives an output's messages outside the chain.
//!
//! The rules are the dora node's: each input's sequence numbers are followed (a gap is counted as
//! missing), an output's end announces the count its sequence numbers cover, a stage is finished
//! once every input ended (or it stopped), and a stage that fails ends its outputs cut short,
//! which cuts every stream downstream; the chain runs to its end and then returns the first
//! error, so that the stages downstream (a sink) still write what they received.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use eyre::{bail, eyre};
use neuspike_schemas::{SeqStatus, SeqTracker};

use crate::{Flow, Msg, Outbox, Port, Stage, Tallies, Tally, unix_now_ns};

/// Stages wired output to input in one process. See the module's docs.
pub struct Chain<'a> {
    slots: Vec<Slot<'a>>,
    edges: Vec<Edge>,
    taps: Vec<Tap<'a>>,
    queue: VecDeque<Item>,
    error: Option<eyre::Report>,
}

struct Slot<'a> {
    id: String,
    stage: Box<dyn Stage + 'a>,
    inputs: Vec<InputSlot>,
    outputs: Vec<OutputSlot>,
    done: bool,
    /// Whether it stopped before its inputs ended (it had all it needed).
    stopped: bool,
    cut: bool,
    /// The newest origin stamp among the messages it took.
    origin: Option<i64>,
    busy: Duration,
    received: u64,
    sent: u64,
    /// Messages that came after the stage stopped.
    dropped: u64,
}

struct InputSlot {
    port: Port,
    seq: SeqTracker,
    ended: bool,
    cut: bool,
}

struct OutputSlot {
    port: Port,
    count: u64,
    ended: bool,
}

struct Edge {
    from: usize,
    output: String,
    to: usize,
    input: String,
}

/// A receiver of an output's messages outside the chain.
type TapFn<'a> = Box<dyn FnMut(Msg) -> eyre::Result<()> + 'a>;

struct Tap<'a> {
    from: usize,
    output: String,
    f: TapFn<'a>,
}

// A message travels by value through the queue (a box per message would cost an allocation
// on the hot path); the queue holds a handful at a time.
#[allow(clippy::large_enum_variant)]
enum Item {
    Message {
        to: usize,
        input: String,
        msg: Msg,
        origin: i64,
    },
    End {
        to: usize,
        input: String,
        count: u64,
        cut: bool,
    },
}

/// What one stage of a run did.
#[derive(Clone, Debug)]
pub struct StageReport {
    /// Its id in the chain.
    pub id: String,
    /// Time spent in its calls.
    pub busy: Duration,
    /// Messages it received.
    pub received: u64,
    /// Messages it sent.
    pub sent: u64,
    /// Its inputs' tallies.
    pub inputs: Tallies,
    /// Whether its outputs were cut short.
    pub cut: bool,
    /// Whether it stopped before its inputs ended (it had all it needed: the messages after
    /// were dropped, not lost).
    pub stopped: bool,
}

/// What a run of a chain did, stage by stage.
#[derive(Clone, Debug)]
pub struct ChainReport {
    /// Every stage, in the order they were added.
    pub stages: Vec<StageReport>,
    /// The run's wall time.
    pub wall: Duration,
}

impl ChainReport {
    /// The report of stage `id`.
    pub fn stage(&self, id: &str) -> Option<&StageReport> {
        self.stages.iter().find(|s| s.id == id)
    }

    /// Messages known to be missing, over every stage's inputs.
    pub fn missing(&self) -> u64 {
        self.stages.iter().map(|s| s.inputs.missing()).sum()
    }
}

/// `node/port` split at its slash.
fn address(s: &str) -> eyre::Result<(&str, &str)> {
    s.split_once('/')
        .filter(|(n, p)| !n.is_empty() && !p.is_empty())
        .ok_or_else(|| eyre!("chain: `{s}` is not `stage/port`"))
}

impl Default for Chain<'_> {
    fn default() -> Self {
        Self::new()
    }
}

impl<'a> Chain<'a> {
    /// An empty chain.
    pub fn new() -> Self {
        Chain {
            slots: Vec::new(),
            edges: Vec::new(),
            taps: Vec::new(),
            queue: VecDeque::new(),
            error: None,
        }
    }

    /// Adds `stage` under `id`.
    ///
    /// # Errors
    /// The id is taken, holds a slash, or the stage declares a port twice.
    pub fn add(&mut self, id: &str, stage: impl Stage + 'a) -> eyre::Result<&mut Self> {
        if id.is_empty() || id.contains('/') {
            bail!("chain: stage id `{id}` must be non-empty and without a slash");
        }
        if self.slots.iter().any(|s| s.id == id) {
            bail!("chain: stage id `{id}` is used twice");
        }
        let inputs = stage.inputs();
        let outputs = stage.outputs();
        for ports in [&inputs, &outputs] {
            for (i, p) in ports.iter().enumerate() {
                if ports[..i].iter().any(|q| q.id == p.id) {
                    bail!("chain: stage `{id}` declares port `{}` twice", p.id);
                }
            }
        }
        self.slots.push(Slot {
            id: id.to_string(),
            stage: Box::new(stage),
            inputs: inputs
                .into_iter()
                .map(|port| InputSlot {
                    port,
                    seq: SeqTracker::default(),
                    ended: false,
                    cut: false,
                })
                .collect(),
            outputs: outputs
                .into_iter()
                .map(|port| OutputSlot {
                    port,
                    count: 0,
                    ended: false,
                })
                .collect(),
            done: false,
            stopped: false,
            cut: false,
            origin: None,
            busy: Duration::ZERO,
            received: 0,
            sent: 0,
            dropped: 0,
        });
        Ok(self)
    }

    fn slot(&self, id: &str) -> eyre::Result<usize> {
        self.slots
            .iter()
            .position(|s| s.id == id)
            .ok_or_else(|| eyre!("chain: no stage `{id}`"))
    }

    /// The output `from` (`stage/output`): its stage and port.
    fn output(&self, from: &str) -> eyre::Result<(usize, &Port)> {
        let (node, port) = address(from)?;
        let i = self.slot(node)?;
        let p = self.slots[i]
            .outputs
            .iter()
            .find(|o| o.port.id == port)
            .map(|o| &o.port)
            .ok_or_else(|| {
                eyre!(
                    "chain: stage `{node}` has no output `{port}` (it has: {})",
                    names(self.slots[i].outputs.iter().map(|o| &o.port))
                )
            })?;
        Ok((i, p))
    }

    /// Feeds input `to` (`stage/input`) with output `from` (`stage/output`).
    ///
    /// # Errors
    /// Either end does not exist, their types differ, or the input already has a sender.
    pub fn connect(&mut self, from: &str, to: &str) -> eyre::Result<&mut Self> {
        let (f, out) = self.output(from)?;
        let out = out.clone();
        let (node, port) = address(to)?;
        let t = self.slot(node)?;
        let input = self.slots[t]
            .inputs
            .iter()
            .find(|i| i.port.id == port)
            .map(|i| &i.port)
            .ok_or_else(|| {
                eyre!(
                    "chain: stage `{node}` has no input `{port}` (it has: {})",
                    names(self.slots[t].inputs.iter().map(|i| &i.port))
                )
            })?;
        if input.ty != out.ty {
            bail!(
                "chain: `{from}` sends {} but `{to}` reads {}",
                out.ty,
                input.ty
            );
        }
        if let Some(e) = self.edges.iter().find(|e| e.to == t && e.input == port) {
            bail!(
                "chain: `{to}` is fed twice: by `{}/{}` and by `{from}`",
                self.slots[e.from].id,
                e.output
            );
        }
        self.edges.push(Edge {
            from: f,
            output: out.id,
            to: t,
            input: port.to_string(),
        });
        Ok(self)
    }

    /// Hands every message of output `from` (`stage/output`) to `f`, in order, as the chain
    /// runs. An error of `f` fails the run as a stage's would.
    ///
    /// # Errors
    /// The output does not exist.
    pub fn tap(
        &mut self,
        from: &str,
        f: impl FnMut(Msg) -> eyre::Result<()> + 'a,
    ) -> eyre::Result<&mut Self> {
        let (i, port) = self.output(from)?;
        let output = port.id.clone();
        self.taps.push(Tap {
            from: i,
            output,
            f: Box::new(f),
        });
        Ok(self)
    }

    /// Runs every stage to its end: the sources step in turn until each has stopped, every
    /// message handed on as it is sent.
    ///
    /// # Errors
    /// An input nobody feeds (before anything runs); else the first error of a stage or a tap,
    /// returned once the run has ended (the stages after it ended their streams cut short).
    pub fn run(mut self) -> eyre::Result<ChainReport> {
        for s in &self.slots {
            for i in &s.inputs {
                if !self
                    .edges
                    .iter()
                    .any(|e| self.slots[e.to].id == s.id && e.input == i.port.id)
                {
                    bail!(
                        "chain: input `{}/{}` ({}) is fed by no stage",
                        s.id,
                        i.port.id,
                        i.port.ty
                    );
                }
            }
        }
        let start = Instant::now();
        let sources: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots[i].inputs.is_empty())
            .collect();
        loop {
            let mut stepped = false;
            for &s in &sources {
                if self.slots[s].done {
                    continue;
                }
                stepped = true;
                if self.consumers_gone(s) {
                    tracing::warn!(
                        stage = self.slots[s].id,
                        "every stage this source feeds has ended before it: stopping"
                    );
                    self.finish(s);
                } else {
                    let mut out = Outbox::new();
                    let t = Instant::now();
                    let r = self.slots[s].stage.step(&mut out);
                    self.slots[s].busy += t.elapsed();
                    self.dispatch(s, &mut out);
                    self.after(s, r);
                }
                self.drain();
            }
            if !stepped {
                break;
            }
        }
        // A stage whose inputs never ended (a cycle): finished with what it has.
        for i in 0..self.slots.len() {
            if !self.slots[i].done {
                tracing::error!(stage = self.slots[i].id, "inputs never ended: finished");
                self.finish(i);
                self.drain();
            }
        }
        let wall = start.elapsed();
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        Ok(ChainReport {
            stages: self
                .slots
                .iter()
                .map(|s| StageReport {
                    id: s.id.clone(),
                    busy: s.busy,
                    received: s.received,
                    sent: s.sent,
                    inputs: tallies(s),
                    cut: s.cut,
                    stopped: s.stopped,
                })
                .collect(),
            wall,
        })
    }

    /// Whether every consumer of the outputs of `s` has stopped (none: false).
    fn consumers_gone(&self, s: usize) -> bool {
        let mut fed = self.edges.iter().filter(|e| e.from == s).peekable();
        fed.peek().is_some()
            && self.taps.iter().all(|t| t.from != s)
            && fed.all(|e| self.slots[e.to].done)
    }

    fn fail(&mut self, s: usize, e: eyre::Report) {
        let id = self.slots[s].id.clone();
        tracing::error!(stage = id, "{e:#}");
        self.slots[s].cut = true;
        if self.error.is_none() {
            self.error = Some(e.wrap_err(format!("stage `{id}`")));
        }
    }

    /// What a call of stage `s` returned.
    fn after(&mut self, s: usize, r: eyre::Result<Flow>) {
        match r {
            Ok(Flow::Continue) => {}
            Ok(Flow::Stop) => self.finish(s),
            Err(e) => {
                self.fail(s, e);
                self.finish(s);
            }
        }
    }

    /// Hands on what stage `s` put in `out`.
    fn dispatch(&mut self, s: usize, out: &mut Outbox) {
        let sent: Vec<_> = out.take_sent().collect();
        for sent in sent {
            let slot = &mut self.slots[s];
            let Some(o) = slot.outputs.iter_mut().find(|o| o.port.id == sent.output) else {
                let e = eyre!(
                    "sent on output `{}`, which it does not declare",
                    sent.output
                );
                self.fail(s, e);
                continue;
            };
            if o.ended {
                let e = eyre!("sent on output `{}` after its end", sent.output);
                self.fail(s, e);
                continue;
            }
            if sent.msg.ty() != o.port.ty {
                let e = eyre!(
                    "sent a {} on output `{}`, which carries {}",
                    sent.msg.ty(),
                    sent.output,
                    o.port.ty
                );
                self.fail(s, e);
                continue;
            }
            o.count = o.count.max(sent.msg.seq().saturating_add(1));
            slot.sent += 1;
            let origin = sent
                .origin_unix_ns
                .or(slot.origin)
                .unwrap_or_else(unix_now_ns);
            if sent.origin_unix_ns.is_some() {
                slot.origin = sent.origin_unix_ns;
            }
            let consumers: Vec<(usize, String)> = self
                .edges
                .iter()
                .filter(|e| e.from == s && e.output == sent.output)
                .map(|e| (e.to, e.input.clone()))
                .collect();
            let taps: Vec<usize> = (0..self.taps.len())
                .filter(|&t| self.taps[t].from == s && self.taps[t].output == sent.output)
                .collect();
            let mut left = consumers.len() + taps.len();
            let mut msg = Some(sent.msg);
            let mut take = |left: &mut usize| {
                *left -= 1;
                if *left == 0 { msg.take() } else { msg.clone() }
            };
            for t in taps {
                if let Some(m) = take(&mut left)
                    && let Err(e) = (self.taps[t].f)(m)
                {
                    self.fail(s, e.wrap_err(format!("a tap of `{}`", sent.output)));
                }
            }
            for (to, input) in consumers {
                if let Some(msg) = take(&mut left) {
                    self.queue.push_back(Item::Message {
                        to,
                        input,
                        msg,
                        origin,
                    });
                }
            }
        }
        let counts: Vec<_> = out.take_at_least().collect();
        for (output, count) in counts {
            match self.slots[s]
                .outputs
                .iter_mut()
                .find(|o| o.port.id == output)
            {
                Some(o) => o.count = o.count.max(count),
                None => {
                    let e = eyre!("counted output `{output}`, which it does not declare");
                    self.fail(s, e);
                }
            }
        }
        if out.take_cut() {
            self.slots[s].cut = true;
        }
    }

    /// Stage `s` is done: what it holds goes out, then every output's end.
    fn finish(&mut self, s: usize) {
        if self.slots[s].done {
            return;
        }
        self.slots[s].done = true;
        let t = tallies(&self.slots[s]);
        let mut out = Outbox::new();
        let start = Instant::now();
        let r = self.slots[s].stage.finish(&t, &mut out);
        self.slots[s].busy += start.elapsed();
        self.dispatch(s, &mut out);
        if let Err(e) = r {
            self.fail(s, e);
        }
        let slot = &mut self.slots[s];
        if slot.dropped > 0 {
            tracing::warn!(
                stage = slot.id,
                dropped = slot.dropped,
                "messages came after the stage stopped"
            );
        }
        let cut = slot.cut;
        let ends: Vec<(String, u64)> = slot
            .outputs
            .iter_mut()
            .filter(|o| !o.ended)
            .map(|o| {
                o.ended = true;
                (o.port.id.clone(), o.count)
            })
            .collect();
        for (output, count) in ends {
            let consumers: Vec<(usize, String)> = self
                .edges
                .iter()
                .filter(|e| e.from == s && e.output == output)
                .map(|e| (e.to, e.input.clone()))
                .collect();
            for (to, input) in consumers {
                self.queue.push_back(Item::End {
                    to,
                    input,
                    count,
                    cut,
                });
            }
        }
    }

    /// Hands on every queued message and end, and what the stages send in turn.
    fn drain(&mut self) {
        while let Some(item) = self.queue.pop_front() {
            match item {
                Item::Message {
                    to,
                    input,
                    msg,
                    origin,
                } => self.deliver(to, &input, msg, origin),
                Item::End {
                    to,
                    input,
                    count,
                    cut,
                } => self.end(to, &input, count, cut),
            }
        }
    }

    fn deliver(&mut self, to: usize, input: &str, msg: Msg, origin: i64) {
        let slot = &mut self.slots[to];
        if slot.done {
            slot.dropped += 1;
            return;
        }
        let Some(i) = slot.inputs.iter_mut().find(|i| i.port.id == input) else {
            return;
        };
        let seq = msg.seq();
        match i.seq.observe(seq) {
            SeqStatus::InOrder => {}
            SeqStatus::Gap { missing } => {
                tracing::error!(
                    stage = slot.id,
                    input,
                    seq,
                    missing,
                    "messages lost before this one"
                );
            }
            SeqStatus::Stale => tracing::warn!(stage = slot.id, input, seq, "stale message"),
        }
        slot.received += 1;
        slot.origin = Some(slot.origin.map_or(origin, |o| o.max(origin)));
        let mut out = Outbox::new();
        out.set_incoming_origin(Some(origin));
        let start = Instant::now();
        let r = slot.stage.on_message(input, msg, &mut out);
        slot.busy += start.elapsed();
        if matches!(r, Ok(Flow::Stop)) {
            slot.stopped = slot.inputs.iter().any(|i| !i.ended);
        }
        self.dispatch(to, &mut out);
        self.after(to, r);
    }

    fn end(&mut self, to: usize, input: &str, count: u64, cut: bool) {
        let slot = &mut self.slots[to];
        if slot.done {
            return;
        }
        let Some(i) = slot.inputs.iter_mut().find(|i| i.port.id == input) else {
            return;
        };
        let lost = i.seq.end(count);
        i.ended = true;
        i.cut = cut;
        if lost > 0 {
            tracing::error!(
                stage = slot.id,
                input,
                lost,
                "messages lost at the end of the stream"
            );
        }
        if cut {
            tracing::error!(
                stage = slot.id,
                input,
                "the stream was cut short: a stage upstream failed"
            );
            slot.cut = true;
        }
        let mut out = Outbox::new();
        let start = Instant::now();
        let r = slot.stage.on_end(input, count, &mut out);
        slot.busy += start.elapsed();
        let all_ended = slot.inputs.iter().all(|i| i.ended);
        if matches!(r, Ok(Flow::Stop)) && !all_ended {
            slot.stopped = true;
        }
        self.dispatch(to, &mut out);
        match r {
            Ok(Flow::Continue) if !all_ended => {}
            other => self.after(to, other.map(|_| Flow::Stop)),
        }
    }
}

fn tallies(s: &Slot<'_>) -> Tallies {
    Tallies(
        s.inputs
            .iter()
            .map(|i| (i.port.id.clone(), Tally::from_seq(&i.seq, i.ended, i.cut)))
            .collect(),
    )
}

fn names<'p>(ports: impl Iterator<Item = &'p Port>) -> String {
    let v: Vec<&str> = ports.map(|p| p.id.as_str()).collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

#[cfg(test)]
mod tests;
