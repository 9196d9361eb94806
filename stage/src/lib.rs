//! The stage: the unit every neuspike pipeline is made of, with or without dora.
//!
//! A [`Stage`] is a state machine over typed messages: it declares its input and output
//! [`Port`]s, takes each message of an input in sequence order ([`Stage::on_message`]) and each
//! input's end of stream ([`Stage::on_end`]), sends what it makes through an [`Outbox`], and, once
//! every input has ended, sends what it still holds ([`Stage::finish`]). A source has no inputs:
//! the driver calls [`Stage::step`] until it says [`Flow::Stop`].
//!
//! Two drivers run stages, with the same rules for order, loss and the end of a stream:
//!
//! - the dora node (`neuspike_runtime::run_stage`): one stage per process, its messages Arrow on
//!   dora's links, flow controlled by credits;
//! - the [`Chain`]: stages in one process, messages handed over as Rust values (moved, cloned only
//!   where two consumers read one output), no dora and no zenoh; made one stage ([`Fused`]), a
//!   chain runs inside a dora node too: several stages in one process.
//!
//! The rules, shared by both:
//!
//! - An output counts the messages its sequence numbers cover (one past the highest sent, or more
//!   with [`Outbox::at_least`]): its end of stream announces that count, so a consumer can tell a
//!   message lost anywhere, the tail included ([`Tally`]).
//! - A stream that ends because a stage failed, or that read a stream cut short, is [`Tally::cut`]
//!   (the stage's own outputs too, down to the sink's summary).
#![deny(missing_docs)]

pub mod chain;
mod fused;
mod message;
mod pace;
mod replay;

pub use chain::{Chain, ChainReport, StageReport};
pub use fused::Fused;
pub use message::{Msg, MsgType, WrongType};
pub use pace::{Pace, Pacer, unix_now_ns};
pub use replay::Replay;

use neuspike_schemas::SeqTracker;

/// A named input or output of a stage and the type of the messages on it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Port {
    /// The id in the graph (`spikes`, `windows`, `tfp`, `frames`, ...).
    pub id: String,
    /// What travels on it.
    pub ty: MsgType,
}

impl Port {
    /// Port `id` carrying `ty`.
    pub fn new(id: impl Into<String>, ty: MsgType) -> Self {
        Port { id: id.into(), ty }
    }
}

/// Whether a stage goes on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Take the next message (a source: make the next ones).
    Continue,
    /// The stage has all it needs (a source: it is done).
    Stop,
}

/// What a stage sends while it handles one call: messages by output, counts, the origin stamp.
#[derive(Debug, Default)]
pub struct Outbox {
    sent: Vec<Sent>,
    at_least: Vec<(String, u64)>,
    cut: bool,
    /// The origin of the message being handled.
    incoming: Option<i64>,
    /// The origin the stage set for what it sends.
    stamp: Option<i64>,
}

/// One message a stage sent, with the origin stamp it set, if any.
#[derive(Debug)]
pub struct Sent {
    /// The output's id.
    pub output: String,
    /// The message.
    pub msg: Msg,
    /// The wall-clock time its newest camera data left its source, when the stage set it
    /// ([`Outbox::set_origin`]); else the driver stamps the newest origin the stage took.
    pub origin_unix_ns: Option<i64>,
}

impl Outbox {
    /// An empty outbox.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sends `msg` on output `output`.
    pub fn send(&mut self, output: &str, msg: impl Into<Msg>) {
        self.sent.push(Sent {
            output: output.to_string(),
            msg: msg.into(),
            origin_unix_ns: self.stamp,
        });
    }

    /// Makes output `output` announce at least `count` messages at its end: a stage whose input
    /// lost its last messages passes the sender's count on, so the loss shows downstream too.
    pub fn at_least(&mut self, output: &str, count: u64) {
        self.at_least.push((output.to_string(), count));
    }

    /// Marks every output of the stage cut short (a stream it relays was cut where it was made).
    pub fn mark_cut(&mut self) {
        self.cut = true;
    }

    /// Stamps the messages sent after this call with `unix_ns` as their origin: a paced source
    /// stamps when its camera would have delivered the data ([`Pacer::wait_until`]).
    pub fn set_origin(&mut self, unix_ns: i64) {
        self.stamp = Some(unix_ns);
    }

    /// The origin stamp of the message being handled (set by the driver before
    /// [`Stage::on_message`]): when its newest camera data left its source, if it says.
    pub fn origin_unix_ns(&self) -> Option<i64> {
        self.incoming
    }

    /// The driver's side: the stamp of the message it hands the stage next.
    pub fn set_incoming_origin(&mut self, unix_ns: Option<i64>) {
        self.incoming = unix_ns;
    }

    /// The driver's side: what was sent since the last call, in order.
    pub fn take_sent(&mut self) -> std::vec::Drain<'_, Sent> {
        self.sent.drain(..)
    }

    /// The driver's side: the counts asked for since the last call.
    pub fn take_at_least(&mut self) -> std::vec::Drain<'_, (String, u64)> {
        self.at_least.drain(..)
    }

    /// The driver's side: whether the stage marked its outputs cut (cleared).
    pub fn take_cut(&mut self) -> bool {
        std::mem::take(&mut self.cut)
    }
}

/// One input's stream as the driver followed it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// The count its end of stream announced, if it came.
    pub announced: Option<u64>,
    /// Messages received.
    pub received: u64,
    /// Messages known to be missing (gaps in the sequence numbers, and the tail).
    pub missing: u64,
    /// Messages refused, not lost: a sequence number far past the stream's
    /// ([`neuspike_schemas::SeqStatus::Anomaly`]), or an end announcing far too many.
    pub refused: u64,
    /// Whether the stream ended.
    pub ended: bool,
    /// Whether it was cut short: its sender failed, or a stage upstream did.
    pub cut: bool,
}

impl Tally {
    /// The tally of a stream followed by `seq`.
    pub fn from_seq(seq: &SeqTracker, ended: bool, cut: bool) -> Self {
        Tally {
            announced: seq.announced(),
            received: seq.received(),
            missing: seq.missing(),
            refused: seq.anomalies(),
            ended,
            cut,
        }
    }
}

/// Every input's tally, by input id.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Tallies(pub Vec<(String, Tally)>);

impl Tallies {
    /// The tally of input `id`.
    pub fn get(&self, id: &str) -> Option<&Tally> {
        self.0.iter().find(|(k, _)| k == id).map(|(_, t)| t)
    }

    /// Every input and its tally.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &Tally)> {
        self.0.iter().map(|(k, t)| (k.as_str(), t))
    }

    /// Messages known to be missing, over every input.
    pub fn missing(&self) -> u64 {
        self.0.iter().map(|(_, t)| t.missing).sum()
    }

    /// The largest count an end of stream announced (0 before any).
    pub fn announced(&self) -> u64 {
        self.0
            .iter()
            .filter_map(|(_, t)| t.announced)
            .max()
            .unwrap_or(0)
    }

    /// Whether any input was cut short.
    pub fn cut(&self) -> bool {
        self.0.iter().any(|(_, t)| t.cut)
    }
}

/// A stage of a pipeline: typed messages in, messages out, end of stream. See the crate's docs.
///
/// The driver hands each input's messages in sequence order, never after the input's end, and
/// calls [`Stage::finish`] once, after every input ended or a call returned [`Flow::Stop`]; then
/// it ends every output with the count its sequence numbers cover.
pub trait Stage: Send {
    /// The stage's name in logs and errors (`align`, `infer`, ...).
    fn name(&self) -> &str;

    /// The inputs it reads (none: a source).
    fn inputs(&self) -> Vec<Port>;

    /// The outputs it sends on.
    fn outputs(&self) -> Vec<Port>;

    /// A source's next messages; [`Flow::Stop`] when it has sent all it has. The default, for a
    /// stage with inputs, makes nothing.
    ///
    /// # Errors
    /// The source failed; what it sent before stays a whole stream.
    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        let _ = out;
        Ok(Flow::Stop)
    }

    /// The next message of `input`.
    ///
    /// # Errors
    /// The message is not one the stage can take (an error naming the stage, the input and why).
    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow>;

    /// `input` ended after `count` messages.
    ///
    /// # Errors
    /// What the stage held for the input could not be sent.
    fn on_end(&mut self, input: &str, count: u64, out: &mut Outbox) -> eyre::Result<Flow> {
        let _ = (input, count, out);
        Ok(Flow::Continue)
    }

    /// Every input ended (their tallies in `inputs`), or the stage stopped: what it still holds
    /// goes out, with the counts its outputs announce.
    ///
    /// # Errors
    /// What the stage held could not be made or written.
    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        let _ = (inputs, out);
        Ok(())
    }
}

impl<S: Stage + ?Sized> Stage for Box<S> {
    fn name(&self) -> &str {
        (**self).name()
    }
    fn inputs(&self) -> Vec<Port> {
        (**self).inputs()
    }
    fn outputs(&self) -> Vec<Port> {
        (**self).outputs()
    }
    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        (**self).step(out)
    }
    fn on_message(&mut self, input: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        (**self).on_message(input, msg, out)
    }
    fn on_end(&mut self, input: &str, count: u64, out: &mut Outbox) -> eyre::Result<Flow> {
        (**self).on_end(input, count, out)
    }
    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        (**self).finish(inputs, out)
    }
}
