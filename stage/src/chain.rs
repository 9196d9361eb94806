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
//!
//! A chain may also have ports of its own: an [`Chain::inlet`] hands messages from outside to
//! stages' inputs, an [`Chain::outlet`] sends a stage's output out. [`Chain::into_stage`] makes
//! such a chain one [`Stage`] (a [`crate::Fused`] stage), which a driver runs like any other:
//! several stages in one dora node, one process. Its sources and sinks may each run on a thread
//! of their own ([`Chain::run_on_threads`]), messages handed over bounded channels: a source
//! that gets ahead, or a chain that gets ahead of its sink, waits; nothing is dropped.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use eyre::{bail, eyre};
use neuspike_schemas::{SeqStatus, SeqTracker};

use crate::{Flow, Msg, MsgType, Outbox, Port, Stage, Tallies, Tally, unix_now_ns};

/// Stages wired output to input in one process. See the module's docs.
pub struct Chain<'a> {
    slots: Vec<Slot<'a>>,
    edges: Vec<Edge>,
    taps: Vec<Tap<'a>>,
    inlets: Vec<Inlet>,
    outlets: Vec<Outlet>,
    /// What the outlets sent since it was last taken, in order.
    exported: Vec<Exported>,
    threads: Option<Threads>,
    queue: VecDeque<Item>,
    error: Option<eyre::Report>,
}

/// An input of the chain itself: each message goes to one or more stages' inputs.
struct Inlet {
    name: String,
    ty: MsgType,
    to: Vec<(usize, String)>,
}

/// An output of the chain itself: a stage's output, sent out.
struct Outlet {
    name: String,
    ty: MsgType,
    from: usize,
    output: String,
}

/// A message an outlet sent.
pub(crate) struct Exported {
    /// The outlet's index.
    pub outlet: usize,
    pub msg: Msg,
    pub origin: i64,
}

/// The sources that run on threads of their own: what they make arrives on one channel.
struct Threads {
    rx: Receiver<(usize, Batch)>,
    /// Sources whose last batch has not come.
    live: usize,
    /// Set when the chain no longer takes what they make.
    stop: Vec<(usize, Arc<AtomicBool>)>,
}

/// What a source on a thread made in one step (its finish in the last).
struct Batch {
    out: Outbox,
    flow: eyre::Result<Flow>,
    busy: Duration,
    last: bool,
}

/// Batches a source thread may make ahead of the chain, over every source thread.
const AHEAD: usize = 16;

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
    /// Whether the stage runs on a thread of its own (a source).
    remote: bool,
    /// A stage without outputs on a thread of its own.
    worker: Option<worker::Worker>,
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
type TapFn<'a> = Box<dyn FnMut(Msg) -> eyre::Result<()> + Send + 'a>;

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

    /// A Markdown table: each stage's time in its calls (and its share of the wall time), the
    /// messages it received and sent, and those its inputs missed. A source's time includes
    /// the waits of its pace.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::from(
            "| stage | busy s | share | received | sent | missing |\n|---|---:|---:|---:|---:|---:|\n",
        );
        // A wall time of zero (nothing ran) makes every share 0.
        let wall = self.wall.as_secs_f64();
        for st in &self.stages {
            let busy = st.busy.as_secs_f64();
            let share = if wall > 0.0 { 100.0 * busy / wall } else { 0.0 };
            let _ = writeln!(
                s,
                "| {} | {busy:.3} | {share:.0}% | {} | {} | {} |",
                st.id,
                st.received,
                st.sent,
                st.inputs.missing()
            );
        }
        s
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
            inlets: Vec::new(),
            outlets: Vec::new(),
            exported: Vec::new(),
            threads: None,
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
            remote: false,
            worker: None,
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

    /// The input `to` (`stage/input`): its stage, id and type.
    fn input(&self, to: &str) -> eyre::Result<(usize, String, MsgType)> {
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
        Ok((t, port.to_string(), input.ty))
    }

    /// What feeds input `port` of stage `t` already, if anything: `stage/output` or `inlet X`.
    fn feeder(&self, t: usize, port: &str) -> Option<String> {
        if let Some(e) = self.edges.iter().find(|e| e.to == t && e.input == port) {
            return Some(format!("`{}/{}`", self.slots[e.from].id, e.output));
        }
        self.inlets
            .iter()
            .find(|i| i.to.iter().any(|(s, p)| *s == t && p == port))
            .map(|i| format!("inlet `{}`", i.name))
    }

    /// Feeds input `to` (`stage/input`) with output `from` (`stage/output`).
    ///
    /// # Errors
    /// Either end does not exist, their types differ, or the input already has a sender.
    pub fn connect(&mut self, from: &str, to: &str) -> eyre::Result<&mut Self> {
        let (f, out) = self.output(from)?;
        let out = out.clone();
        let (t, port, ty) = self.input(to)?;
        if ty != out.ty {
            bail!("chain: `{from}` sends {} but `{to}` reads {ty}", out.ty);
        }
        if let Some(by) = self.feeder(t, &port) {
            bail!("chain: `{to}` is fed twice: by {by} and by `{from}`");
        }
        self.edges.push(Edge {
            from: f,
            output: out.id,
            to: t,
            input: port,
        });
        Ok(self)
    }

    /// Feeds input `to` (`stage/input`) from the chain's own input `name`: what is handed to
    /// the chain's stage ([`Chain::into_stage`]) on `name` goes there. Several inputs may read
    /// one inlet.
    ///
    /// # Errors
    /// The input does not exist or already has a sender, or the inlet carries another type.
    pub fn inlet(&mut self, name: &str, to: &str) -> eyre::Result<&mut Self> {
        let (t, port, ty) = self.input(to)?;
        if let Some(by) = self.feeder(t, &port) {
            bail!("chain: `{to}` is fed twice: by {by} and by inlet `{name}`");
        }
        match self.inlets.iter_mut().find(|i| i.name == name) {
            Some(i) if i.ty != ty => {
                bail!(
                    "chain: inlet `{name}` carries {} but `{to}` reads {ty}",
                    i.ty
                )
            }
            Some(i) => i.to.push((t, port)),
            None => self.inlets.push(Inlet {
                name: name.to_string(),
                ty,
                to: vec![(t, port)],
            }),
        }
        Ok(self)
    }

    /// Sends output `from` (`stage/output`) out of the chain as its own output `name`.
    ///
    /// # Errors
    /// The output does not exist, or the name is taken.
    pub fn outlet(&mut self, name: &str, from: &str) -> eyre::Result<&mut Self> {
        let (f, port) = self.output(from)?;
        let (ty, output) = (port.ty, port.id.clone());
        if self.outlets.iter().any(|o| o.name == name) {
            bail!("chain: outlet `{name}` is declared twice");
        }
        self.outlets.push(Outlet {
            name: name.to_string(),
            ty,
            from: f,
            output,
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
        f: impl FnMut(Msg) -> eyre::Result<()> + Send + 'a,
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
    /// An input nobody feeds, or an inlet (before anything runs: a chain with inlets runs as a
    /// stage); else the first error of a stage or a tap, returned once the run has ended (the
    /// stages after it ended their streams cut short).
    pub fn run(mut self) -> eyre::Result<ChainReport> {
        self.check_fed()?;
        if let Some(i) = self.inlets.first() {
            bail!(
                "chain: inlet `{}` takes messages from outside: run the chain as a stage",
                i.name
            );
        }
        let start = Instant::now();
        while self.step_sources() {}
        self.finish_rest();
        let wall = start.elapsed();
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        Ok(self.report(wall))
    }

    /// Every input is fed, by a stage or an inlet.
    pub(crate) fn check_fed(&self) -> eyre::Result<()> {
        for (t, s) in self.slots.iter().enumerate() {
            for i in &s.inputs {
                if self.feeder(t, &i.port.id).is_none() {
                    bail!(
                        "chain: input `{}/{}` ({}) is fed by no stage",
                        s.id,
                        i.port.id,
                        i.port.ty
                    );
                }
            }
        }
        Ok(())
    }

    /// Steps each source that runs here once and hands on what the sources on threads made
    /// (waiting for it when no source runs here); returns whether any source was still going.
    pub(crate) fn step_sources(&mut self) -> bool {
        let mut live = false;
        for s in 0..self.slots.len() {
            let slot = &self.slots[s];
            if !slot.inputs.is_empty() || slot.remote || slot.done {
                continue;
            }
            live = true;
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
        if self.threads.as_ref().is_some_and(|t| t.live > 0) {
            let wait = !live;
            live = true;
            while let Some(th) = self.threads.as_mut() {
                let next = if wait {
                    th.rx.recv().map_err(|_| TryRecvError::Disconnected)
                } else {
                    th.rx.try_recv()
                };
                match next {
                    Ok((s, batch)) => {
                        self.take_batch(s, batch);
                        self.drain();
                        if wait {
                            break;
                        }
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        // Every source thread is gone without its last batch: it panicked.
                        th.live = 0;
                        for s in 0..self.slots.len() {
                            if self.slots[s].remote && !self.slots[s].done {
                                self.fail(s, eyre!("its thread ended without finishing"));
                                self.finish(s);
                            }
                        }
                        self.drain();
                        break;
                    }
                }
            }
        }
        live
    }

    /// What source `s`, on a thread of its own, made in one step.
    fn take_batch(&mut self, s: usize, mut batch: Batch) {
        if batch.last
            && let Some(th) = self.threads.as_mut()
        {
            th.live = th.live.saturating_sub(1);
        }
        if self.slots[s].done {
            return;
        }
        self.slots[s].busy += batch.busy;
        if self.consumers_gone(s) {
            tracing::warn!(
                stage = self.slots[s].id,
                "every stage this source feeds has ended before it: stopping"
            );
            self.stop_thread(s);
            self.finish(s);
            return;
        }
        self.dispatch(s, &mut batch.out);
        if batch.last {
            // Its finish ran on its thread: what it sent came in this batch.
            self.after(s, batch.flow.map(|_| Flow::Stop));
        } else {
            self.after(s, batch.flow);
        }
    }

    fn stop_thread(&self, s: usize) {
        if let Some(th) = &self.threads {
            for (i, flag) in &th.stop {
                if *i == s {
                    flag.store(true, Ordering::Relaxed);
                }
            }
        }
    }

    /// Finishes the stages whose inputs never ended (a cycle, or a driver that stopped).
    pub(crate) fn finish_rest(&mut self) {
        for i in 0..self.slots.len() {
            if !self.slots[i].done {
                if self.slots[i].remote {
                    self.stop_thread(i);
                } else if self.slots[i].inputs.iter().any(|p| !p.ended) {
                    tracing::error!(stage = self.slots[i].id, "inputs never ended: finished");
                }
                self.finish(i);
                self.drain();
            }
        }
    }

    /// Whether every stage is done.
    pub(crate) fn all_done(&self) -> bool {
        self.slots.iter().all(|s| s.done)
    }

    /// The first error of a stage or a tap, taken.
    pub(crate) fn take_error(&mut self) -> Option<eyre::Report> {
        self.error.take()
    }

    /// What the stages did so far.
    pub(crate) fn report(&self, wall: Duration) -> ChainReport {
        ChainReport {
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
        }
    }

    /// The chain's own inputs, as ports.
    pub(crate) fn inlet_ports(&self) -> Vec<Port> {
        self.inlets
            .iter()
            .map(|i| Port::new(i.name.clone(), i.ty))
            .collect()
    }

    /// The chain's own outputs, as ports.
    pub(crate) fn outlet_ports(&self) -> Vec<Port> {
        self.outlets
            .iter()
            .map(|o| Port::new(o.name.clone(), o.ty))
            .collect()
    }

    /// Whether the chain has a source.
    pub(crate) fn has_source(&self) -> bool {
        self.slots.iter().any(|s| s.inputs.is_empty())
    }

    /// Hands `msg`, taken on inlet `name` with origin stamp `origin`, to the inputs it feeds,
    /// and on through the chain.
    pub(crate) fn push(&mut self, name: &str, msg: Msg, origin: i64) -> eyre::Result<()> {
        let i = self
            .inlets
            .iter()
            .position(|i| i.name == name)
            .ok_or_else(|| eyre!("chain: no inlet `{name}`"))?;
        let n = self.inlets[i].to.len();
        let mut msg = Some(msg);
        for k in 0..n {
            let (to, input) = self.inlets[i].to[k].clone();
            let m = if k + 1 == n { msg.take() } else { msg.clone() };
            if let Some(msg) = m {
                self.queue.push_back(Item::Message {
                    to,
                    input,
                    msg,
                    origin,
                });
            }
        }
        self.drain();
        Ok(())
    }

    /// Ends inlet `name` after `count` messages: the inputs it feeds end.
    pub(crate) fn push_end(&mut self, name: &str, count: u64, cut: bool) -> eyre::Result<()> {
        let i = self
            .inlets
            .iter()
            .position(|i| i.name == name)
            .ok_or_else(|| eyre!("chain: no inlet `{name}`"))?;
        for (to, input) in self.inlets[i].to.clone() {
            self.queue.push_back(Item::End {
                to,
                input,
                count,
                cut,
            });
        }
        self.drain();
        Ok(())
    }

    /// What the outlets sent since the last call, in order.
    pub(crate) fn take_exported(&mut self) -> std::vec::Drain<'_, Exported> {
        self.exported.drain(..)
    }

    /// The name of outlet `i`.
    pub(crate) fn outlet_name(&self, i: usize) -> &str {
        &self.outlets[i].name
    }

    /// Every outlet's name and the count its stage's output covers so far.
    pub(crate) fn outlet_counts(&self) -> Vec<(String, u64)> {
        self.outlets
            .iter()
            .map(|o| {
                let count = self.slots[o.from]
                    .outputs
                    .iter()
                    .find(|p| p.port.id == o.output)
                    .map_or(0, |p| p.count);
                (o.name.clone(), count)
            })
            .collect()
    }

    /// Whether any stage's outputs were cut short.
    pub(crate) fn any_cut(&self) -> bool {
        self.slots.iter().any(|s| s.cut)
    }

    /// Whether every consumer of the outputs of `s` has stopped (none: false).
    fn consumers_gone(&self, s: usize) -> bool {
        let mut fed = self.edges.iter().filter(|e| e.from == s).peekable();
        fed.peek().is_some()
            && self.taps.iter().all(|t| t.from != s)
            && self.outlets.iter().all(|o| o.from != s)
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
            let outlets: Vec<usize> = (0..self.outlets.len())
                .filter(|&o| self.outlets[o].from == s && self.outlets[o].output == sent.output)
                .collect();
            let mut left = consumers.len() + taps.len() + outlets.len();
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
            for outlet in outlets {
                if let Some(msg) = take(&mut left) {
                    self.exported.push(Exported {
                        outlet,
                        msg,
                        origin,
                    });
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
        let slot = &mut self.slots[s];
        let r = match slot.worker.as_mut() {
            Some(w) => {
                let r = w.finish(t);
                slot.busy += w.take_busy();
                r
            }
            None => {
                let r = slot.stage.finish(&t, &mut out);
                slot.busy += start.elapsed();
                r
            }
        };
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
            SeqStatus::Anomaly { jump } => {
                tracing::warn!(
                    stage = slot.id,
                    input,
                    seq,
                    jump,
                    "a sequence number far past the stream's: refused"
                );
                return;
            }
            SeqStatus::Resynced { jump } => {
                tracing::warn!(
                    stage = slot.id,
                    input,
                    seq,
                    jump,
                    "the stream was renumbered"
                );
            }
            SeqStatus::Restarted { expected } => {
                tracing::warn!(
                    stage = slot.id,
                    input,
                    seq,
                    expected,
                    "the stream's sender restarted"
                );
            }
        }
        slot.received += 1;
        slot.origin = Some(slot.origin.map_or(origin, |o| o.max(origin)));
        let mut out = Outbox::new();
        out.set_incoming_origin(Some(origin));
        let start = Instant::now();
        let r = match slot.worker.as_mut() {
            Some(w) => {
                let r = w.message(input, msg, origin);
                slot.busy += w.take_busy();
                r
            }
            None => {
                let r = slot.stage.on_message(input, msg, &mut out);
                slot.busy += start.elapsed();
                r
            }
        };
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
        let r = match slot.worker.as_mut() {
            Some(w) => {
                let r = w.end(input, count);
                slot.busy += w.take_busy();
                r
            }
            None => {
                let r = slot.stage.on_end(input, count, &mut out);
                slot.busy += start.elapsed();
                r
            }
        };
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

impl Chain<'static> {
    /// Runs each source and each stage without outputs (a sink) on a thread of its own, when
    /// the chain holds anything else; the stages between run on the caller's thread. A source
    /// then makes its next messages while the stages after it handle the last ones, up to a
    /// few steps ahead ([`AHEAD`] over every source), and waits there; a sink takes its
    /// messages while the stages before it make the next ones, up to a few calls behind, and
    /// the chain waits there: nothing is dropped. Every call of a stage, its finish included,
    /// runs on its thread, in the order the chain made them; what a source sends is handed on
    /// in order.
    pub fn run_on_threads(&mut self) {
        if self.threads.is_some() || self.slots.len() < 2 {
            return;
        }
        for s in 0..self.slots.len() {
            let slot = &mut self.slots[s];
            if slot.inputs.is_empty() || !slot.outputs.is_empty() {
                continue;
            }
            let held = Held {
                name: slot.stage.name().to_string(),
                outputs: Vec::new(),
            };
            let stage = std::mem::replace(&mut slot.stage, Box::new(held));
            match worker::Worker::spawn(&slot.id, stage) {
                Ok(w) => slot.worker = Some(w),
                Err(e) => {
                    let e = eyre!("cannot start its thread: {e}");
                    self.fail(s, e);
                    self.finish(s);
                }
            }
        }
        let (tx, rx) = sync_channel::<(usize, Batch)>(AHEAD);
        let mut threads = Threads {
            rx,
            live: 0,
            stop: Vec::new(),
        };
        for s in 0..self.slots.len() {
            if !self.slots[s].inputs.is_empty() {
                continue;
            }
            let slot = &mut self.slots[s];
            let held = Held {
                name: slot.stage.name().to_string(),
                outputs: slot.outputs.iter().map(|o| o.port.clone()).collect(),
            };
            let stage = std::mem::replace(&mut slot.stage, Box::new(held));
            let stop = Arc::new(AtomicBool::new(false));
            let spawned = std::thread::Builder::new()
                .name(format!("stage-{}", slot.id))
                .spawn({
                    let (tx, stop) = (tx.clone(), stop.clone());
                    move || source_thread(s, stage, &tx, &stop)
                });
            match spawned {
                Ok(_) => {
                    slot.remote = true;
                    threads.live += 1;
                    threads.stop.push((s, stop));
                }
                Err(e) => {
                    // The stage went with the closure: it cannot run.
                    tracing::error!(stage = slot.id, "cannot start a thread: {e}");
                    let e = eyre!("cannot start its thread: {e}");
                    self.fail(s, e);
                    self.finish(s);
                }
            }
        }
        self.threads = Some(threads);
    }
}

impl Drop for Chain<'_> {
    fn drop(&mut self) {
        // A source thread still going stops at its next step (or its next send fails).
        if let Some(th) = &self.threads {
            for (_, flag) in &th.stop {
                flag.store(true, Ordering::Relaxed);
            }
        }
    }
}

/// A source's loop on its own thread: steps until it stops, fails or is told to stop, then
/// finishes; every step's messages go to the chain as one batch, the finish's with the last.
fn source_thread(
    s: usize,
    mut stage: Box<dyn Stage>,
    tx: &SyncSender<(usize, Batch)>,
    stop: &AtomicBool,
) {
    loop {
        let mut out = Outbox::new();
        let t = Instant::now();
        let mut flow = if stop.load(Ordering::Relaxed) {
            Ok(Flow::Stop)
        } else {
            stage.step(&mut out)
        };
        let last = !matches!(flow, Ok(Flow::Continue));
        if last && let Err(e) = stage.finish(&Tallies::default(), &mut out) {
            match &flow {
                Ok(_) => flow = Err(e),
                Err(_) => tracing::error!(stage = stage.name(), "{e:#}"),
            }
        }
        let batch = Batch {
            out,
            flow,
            busy: t.elapsed(),
            last,
        };
        if tx.send((s, batch)).is_err() || last {
            return;
        }
    }
}

/// What stays in a source's slot while the source runs on its own thread.
struct Held {
    name: String,
    outputs: Vec<Port>,
}

impl Stage for Held {
    fn name(&self) -> &str {
        &self.name
    }
    fn inputs(&self) -> Vec<Port> {
        Vec::new()
    }
    fn outputs(&self) -> Vec<Port> {
        self.outputs.clone()
    }
    fn on_message(&mut self, _: &str, _: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        Ok(Flow::Stop)
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

mod worker;

#[cfg(test)]
mod tests;
