//! A node's link to its graph: the event stream it reads, the outputs it sends on (declared with
//! their message type, sent with their sequence numbers followed, ended with the count their
//! receivers check), and the credits that flow between them.

use std::collections::{BTreeSet, VecDeque};
use std::time::Instant;

use dora_message::config::{DEFAULT_QUEUE_SIZE, InputMapping};
use dora_node_api::dora_core::config::DataId;
use dora_node_api::{DoraArray, DoraNode, Event, EventStream, StopCause};
use eyre::WrapErr;
use neuspike_schemas::arrow::array::new_empty_array;
use neuspike_schemas::arrow::datatypes::DataType;
use neuspike_schemas::meta::{CUT, LINK_N, ORIGIN_UNIX_NS, SEQ};
use neuspike_schemas::{Credit, Message, MetaExt, end_of_stream_header};

use crate::credit::{CREDITS, CreditLedger, CreditReturns};
use crate::metadata::{meta_from_dora, meta_to_dora};
use crate::{Flow, unix_now_ns};

/// What waiting for an event gave.
pub(crate) enum Polled {
    /// An event for the node.
    Event(Event),
    /// The deadline passed first.
    Timeout,
    /// The event stream ended.
    Ended,
}

struct Output {
    id: DataId,
    data_type: DataType,
    /// One past the highest sequence number sent (or the floor set by [`Link::at_least`]).
    count: u64,
    /// Messages sent on it (the next one's [`LINK_N`]).
    sent: u64,
    ended: bool,
}

/// A node's link to its graph.
///
/// - Outputs: each is declared once with its message type ([`Link::declare`]);
///   [`Link::end_all`] ends every one with the count of messages its sequence numbers cover, so a
///   receiver can tell a message lost anywhere, the tail included.
/// - Events: [`crate::receive`] and [`produce`] read them through the link.
/// - Credits (see [`crate::credit`]): when the graph gives the node an output `credits`, the link
///   grants each of its inputs the input's `queue_size` and returns credits as messages are
///   taken; when the graph gives it inputs fed by other nodes' `credits`, [`Link::send`] waits
///   until every consumer of the output has a credit left. Events that arrive while it waits are
///   kept, in order, for the receive loop.
pub struct Link {
    node: DoraNode,
    events: EventStream,
    /// Events taken off the stream while waiting for credits, not yet handed to the node.
    kept: VecDeque<Event>,
    outputs: Vec<Output>,
    ledger: CreditLedger,
    returns: CreditReturns,
    stop: bool,
    /// The newest origin stamp among the messages taken so far (see [`ORIGIN_UNIX_NS`]).
    origin_unix_ns: Option<i64>,
    /// Whether this node's streams are cut short: it failed, or an input of it was ([`CUT`]).
    cut: bool,
    /// Producers dora restarted whose new process has not been heard from yet.
    restarted: Vec<Restarted>,
}

/// A producer dora restarted: the inputs it feeds, and when to send it its credits again (dora
/// tells of the restart before the new process listens, so the first credits may be lost).
#[derive(Debug)]
struct Restarted {
    producer: String,
    inputs: Vec<String>,
    next: Instant,
}

/// How often a restarted producer is sent its credits until a message from it arrives.
const GREET_EVERY: std::time::Duration = std::time::Duration::from_millis(200);

/// The inputs of `node` that carry its consumers' credits.
pub(crate) fn credit_inputs(node: &DoraNode) -> BTreeSet<String> {
    node.node_config()
        .inputs
        .iter()
        .filter(|(_, input)| {
            matches!(&input.mapping, InputMapping::User(u) if AsRef::<str>::as_ref(&u.output) == CREDITS)
        })
        .map(|(id, _)| id.to_string())
        .collect()
}

impl Link {
    /// The link of `node` reading `events`, no output declared yet. When the graph gives the node
    /// an output `credits`, its first credits (every input with its window) leave now.
    ///
    /// # Errors
    /// The first credits could not be sent.
    pub fn new(node: DoraNode, events: EventStream) -> eyre::Result<Self> {
        let credit_in = credit_inputs(&node);
        let ledger = CreditLedger::new(node.id().as_ref(), &credit_in);
        let config = node.node_config();
        let returns = if config
            .outputs
            .iter()
            .any(|o| AsRef::<str>::as_ref(o) == CREDITS)
        {
            CreditReturns::new(config.inputs.iter().filter_map(
                |(id, input)| match &input.mapping {
                    InputMapping::User(u) if !credit_in.contains(AsRef::<str>::as_ref(id)) => {
                        Some((
                            id.to_string(),
                            format!("{}/{}", u.source, u.output),
                            input.queue_size.unwrap_or(DEFAULT_QUEUE_SIZE) as u64,
                        ))
                    }
                    _ => None,
                },
            ))
        } else {
            CreditReturns::default()
        };
        let mut link = Link {
            node,
            events,
            kept: VecDeque::new(),
            outputs: Vec::new(),
            ledger,
            returns,
            stop: false,
            origin_unix_ns: None,
            cut: false,
            restarted: Vec::new(),
        };
        if let Some(hello) = link.returns.hello() {
            link.send_credit(&hello)?;
        }
        Ok(link)
    }

    /// The dora node (its configuration: the graph's inputs and outputs).
    pub fn node(&self) -> &DoraNode {
        &self.node
    }

    fn send_credit(&mut self, credit: &Credit) -> eyre::Result<()> {
        let (meta, data) = credit.to_arrow();
        self.node
            .send_output(
                DataId::from(CREDITS.to_string()),
                meta_to_dora(&meta),
                DoraArray::from(data),
            )
            .wrap_err("failed to return credits")
    }

    /// Takes credit messages and closed consumers; hands every other event back.
    fn absorb(&mut self, event: Event) -> eyre::Result<Option<Event>> {
        match event {
            Event::Input { id, metadata, data } if self.ledger.is_credit_input(id.as_ref()) => {
                let meta = meta_from_dora(&metadata.parameters);
                let credit = Credit::from_arrow(&meta, data.as_array())
                    .map_err(|e| eyre::eyre!("input `{id}`: {e}"))?;
                tracing::trace!(input = %id, ?credit, "credits");
                self.ledger.grant(id.as_ref(), &credit);
                Ok(None)
            }
            Event::InputClosed { id } if self.ledger.is_credit_input(id.as_ref()) => {
                tracing::debug!(input = %id, "a consumer ended: it holds nothing back any more");
                self.ledger.closed(id.as_ref());
                Ok(None)
            }
            Event::Stop(StopCause::Manual) => {
                self.stop = true;
                Ok(Some(Event::Stop(StopCause::Manual)))
            }
            other => Ok(Some(other)),
        }
    }

    /// The next event for the node (credits are taken on the way); `None` when the stream ended.
    pub(crate) fn next_event(&mut self) -> eyre::Result<Option<Event>> {
        if let Some(e) = self.kept.pop_front() {
            return Ok(Some(e));
        }
        while let Some(e) = self.events.recv() {
            if let Some(e) = self.absorb(e)? {
                return Ok(Some(e));
            }
        }
        Ok(None)
    }

    /// The next event for the node, waiting until `deadline` at most. Past the deadline it
    /// still takes what dora has already queued: [`Polled::Timeout`] means nothing was there.
    pub(crate) fn next_event_until(&mut self, deadline: Instant) -> eyre::Result<Polled> {
        if let Some(e) = self.kept.pop_front() {
            return Ok(Polled::Event(e));
        }
        loop {
            let now = Instant::now();
            if now >= deadline {
                match self.events.try_recv() {
                    Ok(e) => {
                        if let Some(e) = self.absorb(e)? {
                            return Ok(Polled::Event(e));
                        }
                        continue;
                    }
                    Err(dora_node_api::TryRecvError::Empty) => return Ok(Polled::Timeout),
                    Err(dora_node_api::TryRecvError::Closed) => return Ok(Polled::Ended),
                }
            }
            match self.events.recv_timeout(deadline - now) {
                Some(Event::Error(e)) if e.contains("timeout") || e.contains("Timeout") => {
                    return Ok(Polled::Timeout);
                }
                Some(e) => {
                    if let Some(e) = self.absorb(e)? {
                        return Ok(Polled::Event(e));
                    }
                }
                None => return Ok(Polled::Ended),
            }
        }
    }

    /// Counts what dora dropped on this node's inputs since the last call (queues that
    /// overflowed): loss is logged, never silent.
    pub(crate) fn log_drops(&mut self) {
        for (input, n) in self.events.drain_drop_counts() {
            if n > 0 {
                tracing::error!(input = %input, dropped = n, "dora dropped messages: a queue was full");
            }
        }
    }

    /// The producer `producer` was restarted by dora: its new process gets this node's credits
    /// afresh. Returns the inputs it feeds.
    ///
    /// # Errors
    /// The credits could not be sent.
    pub(crate) fn producer_restarted(&mut self, producer: &str) -> eyre::Result<Vec<String>> {
        let fed: Vec<String> = self
            .node
            .node_config()
            .inputs
            .iter()
            .filter(|(id, input)| {
                !self.ledger.is_credit_input(id.as_ref())
                    && matches!(&input.mapping, InputMapping::User(u) if AsRef::<str>::as_ref(&u.source) == producer)
            })
            .map(|(id, _)| id.to_string())
            .collect();
        if let Some(hello) = self.returns.hello_for(producer) {
            self.send_credit(&hello)?;
        }
        self.restarted.retain(|r| r.producer != producer);
        self.restarted.push(Restarted {
            producer: producer.to_string(),
            inputs: fed.clone(),
            next: Instant::now() + GREET_EVERY,
        });
        Ok(fed)
    }

    /// A message arrived on `input`: the restarted producer feeding it has its credits.
    pub(crate) fn heard_on(&mut self, input: &str) {
        if !self.restarted.is_empty() {
            self.restarted
                .retain(|r| !r.inputs.iter().any(|i| i == input));
        }
    }

    /// When a restarted producer not heard from is next sent its credits again.
    pub(crate) fn next_greeting(&self) -> Option<Instant> {
        self.restarted.iter().map(|r| r.next).min()
    }

    /// Sends their credits again to the restarted producers not heard from, when due.
    ///
    /// # Errors
    /// The credits could not be sent.
    pub(crate) fn greet_restarted(&mut self, now: Instant) -> eyre::Result<()> {
        for i in 0..self.restarted.len() {
            if self.restarted[i].next > now {
                continue;
            }
            self.restarted[i].next = now + GREET_EVERY;
            let producer = self.restarted[i].producer.clone();
            if let Some(hello) = self.returns.hello_for(&producer) {
                self.send_credit(&hello)?;
            }
        }
        Ok(())
    }

    /// Marks this node's streams as cut short (their end-of-stream markers say so, see [`CUT`]):
    /// the node failed, or a stream it reads was cut.
    pub fn mark_cut(&mut self) {
        self.cut = true;
    }

    /// Whether this node's streams are cut short (see [`Link::mark_cut`]).
    pub fn is_cut(&self) -> bool {
        self.cut
    }

    /// Sets the origin stamp of this node's next messages (ns since the epoch): a paced source
    /// stamps when the camera would have delivered its data ([`crate::Pacer::wait_until`]).
    pub fn set_origin(&mut self, unix_ns: i64) {
        self.origin_unix_ns = Some(unix_ns);
    }

    /// A message was taken: its origin stamp, if newer, is what this node's next messages carry.
    pub(crate) fn saw(&mut self, meta: &neuspike_schemas::Meta) {
        if let Some(neuspike_schemas::Parameter::Integer(t)) = meta.get(ORIGIN_UNIX_NS) {
            self.origin_unix_ns = Some(self.origin_unix_ns.map_or(*t, |o| o.max(*t)));
        }
    }

    /// One message of `input` was handled, after `lost` that never came: their credits go back
    /// when a batch is due.
    pub(crate) fn taken(&mut self, input: &str, lost: u64) -> eyre::Result<()> {
        self.returns.lost(input, lost);
        match self.returns.taken(input) {
            Some(credit) => self.send_credit(&credit),
            None => Ok(()),
        }
    }

    /// `input` ended: every credit still owed goes back, so that its producer may exit.
    pub(crate) fn ended(&mut self, input: &str) -> eyre::Result<()> {
        match self.returns.ended(input) {
            Some(credit) => self.send_credit(&credit),
            None => Ok(()),
        }
    }

    /// Whether every consumer that returns credits has ended (none: `false`): a source with
    /// nobody left to take its messages stops.
    pub fn consumers_gone(&self) -> bool {
        self.ledger.all_gone()
    }

    /// Whether a stop was asked for (never blocks; a source has no other inputs to wait on).
    pub fn stop_requested(&mut self) -> eyre::Result<bool> {
        while !self.stop {
            match self.events.try_recv() {
                Ok(e) => {
                    if let Some(other) = self.absorb(e)? {
                        tracing::debug!(?other, "ignored event");
                    }
                }
                Err(_) => break,
            }
        }
        if self.stop {
            tracing::info!("stop requested");
        }
        Ok(self.stop)
    }

    /// Waits until every consumer of `output` has a credit left; events that are not credits
    /// are kept for the receive loop.
    fn wait_for_credit(&mut self, output: &str) -> eyre::Result<()> {
        self.wait_while(output, CreditLedger::blocked_on, "sent a credit")
    }

    /// Waits until every consumer of `output` has taken all that was sent on it.
    fn wait_drained(&mut self, output: &str) -> eyre::Result<()> {
        self.wait_while(output, CreditLedger::undrained, "returned every credit")
    }

    /// Takes events while `holder` names a consumer holding `output` back; events that are not
    /// credits are kept for the receive loop.
    fn wait_while(
        &mut self,
        output: &str,
        holder: for<'l> fn(&'l CreditLedger, &str) -> Option<&'l str>,
        awaited: &str,
    ) -> eyre::Result<()> {
        while let Some(consumer) = holder(&self.ledger, output) {
            let consumer = consumer.to_string();
            let Some(e) = self.events.recv() else {
                eyre::bail!(
                    "output `{output}`: the graph ended before input `{consumer}` {awaited}"
                );
            };
            if let Some(e) = self.absorb(e)? {
                self.kept.push_back(e);
            }
        }
        Ok(())
    }

    /// Declares output `id`, carrying messages of type `M`.
    pub fn declare<M: Message>(&mut self, id: &str) -> &mut Self {
        self.declare_as(id, M::data_type())
    }

    /// Declares output `id`, carrying messages whose payload is `data_type` (a stage's port).
    pub fn declare_as(&mut self, id: &str, data_type: DataType) -> &mut Self {
        if !self.declared(id) {
            self.outputs.push(Output {
                id: DataId::from(id.to_string()),
                data_type,
                count: 0,
                sent: 0,
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

    /// Sends `msg` on output `id`, once every consumer of it has a credit left. The message is
    /// stamped with its origin ([`ORIGIN_UNIX_NS`]): the newest stamp this node has taken, or now
    /// for a source.
    ///
    /// # Errors
    /// The output is not declared or already ended, the message has no sequence number, the graph
    /// ended while waiting for credits, or dora refused it.
    pub fn send<M: Message>(&mut self, id: &str, msg: &M) -> eyre::Result<()> {
        let (mut meta, data) = msg.to_arrow();
        let origin = self.origin_unix_ns.unwrap_or_else(unix_now_ns);
        meta.set_int(ORIGIN_UNIX_NS, origin);
        let seq = meta
            .uint("message", SEQ)
            .map_err(|e| eyre::eyre!("output `{id}`: {e}"))?;
        let out = self.output(id)?;
        if out.ended {
            eyre::bail!("output `{id}` was sent a message after its end-of-stream marker");
        }
        let dora_id = out.id.clone();
        self.wait_for_credit(id)?;
        self.ledger.spend(id);
        let out = self.output(id)?;
        out.count = out.count.max(seq.saturating_add(1));
        meta.set_int(LINK_N, i64::try_from(out.sent).unwrap_or(i64::MAX));
        out.sent += 1;
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

    /// Ends every declared output not yet ended with its end-of-stream marker (which waits for
    /// a credit like any message), then, where consumers return credits, waits until they have
    /// taken everything: a message still in flight when a process exits may be lost. Every
    /// output is tried even when one fails; the first failure is returned.
    pub fn end_all(&mut self) -> eyre::Result<()> {
        let mut first_err = None;
        for i in 0..self.outputs.len() {
            if self.outputs[i].ended {
                continue;
            }
            self.outputs[i].ended = true;
            let id = self.outputs[i].id.clone();
            let mut meta = end_marker(self.outputs[i].count, self.cut);
            meta.set_int(
                LINK_N,
                i64::try_from(self.outputs[i].sent).unwrap_or(i64::MAX),
            );
            self.outputs[i].sent += 1;
            let data = new_empty_array(&self.outputs[i].data_type);
            let sent = self.wait_for_credit(id.as_ref()).and_then(|()| {
                self.ledger.spend(id.as_ref());
                self.node
                    .send_output(id.clone(), meta_to_dora(&meta), DoraArray::from(data))
                    .map_err(|e| eyre::eyre!("{e}"))
            });
            if let Err(e) = sent {
                tracing::error!(output = %id, "could not send the end-of-stream marker: {e}");
                first_err.get_or_insert(eyre::eyre!("failed to end output `{id}`: {e}"));
            }
        }
        if first_err.is_none() {
            for i in 0..self.outputs.len() {
                let id = self.outputs[i].id.to_string();
                if let Err(e) = self.wait_drained(&id) {
                    tracing::error!(output = %id, "{e}");
                    first_err.get_or_insert(e);
                }
            }
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The header of an output's end-of-stream marker after `count` messages, flagged [`CUT`] when
/// the stream was cut short.
pub(crate) fn end_marker(count: u64, cut: bool) -> neuspike_schemas::Meta {
    let mut meta = end_of_stream_header(count);
    if cut {
        meta.insert(CUT.to_string(), neuspike_schemas::Parameter::Bool(true));
    }
    meta
}

/// Runs a source: calls `step` (which sends the next messages on `link`) until it returns
/// [`Flow::Stop`] or a stop is requested, then ends every output, whatever happened: after an
/// error the messages already sent still form whole streams, and the error is returned after.
///
/// # Errors
/// The first error of `step`, else of ending the outputs.
pub fn produce(
    link: &mut Link,
    mut step: impl FnMut(&mut Link) -> eyre::Result<Flow>,
) -> eyre::Result<()> {
    produce_with(link, &mut (), |link, ()| step(link), |_, ()| Ok(()))
}

/// [`produce`] over a source's `state`, with `finish` called once the steps are over (whatever
/// happened), before the outputs end.
pub(crate) fn produce_with<S: ?Sized>(
    link: &mut Link,
    state: &mut S,
    mut step: impl FnMut(&mut Link, &mut S) -> eyre::Result<Flow>,
    finish: impl FnOnce(&mut Link, &mut S) -> eyre::Result<()>,
) -> eyre::Result<()> {
    let result = loop {
        match link.stop_requested() {
            Ok(true) => break Ok(()),
            Ok(false) => {}
            Err(e) => break Err(e),
        }
        // Nobody is left to take what the source makes: it stops (the node that failed is
        // reported by the runner; the source ends cleanly).
        if link.consumers_gone() {
            tracing::warn!("every node this source feeds has ended before it: stopping");
            break Ok(());
        }
        match step(link, state) {
            Ok(Flow::Continue) => {}
            Ok(Flow::Stop) => break Ok(()),
            Err(e) => break Err(e),
        }
    };
    let result = result.and(finish(link, state));
    if result.is_err() {
        link.mark_cut();
    }
    let ended = link.end_all();
    result.and(ended)
}

/// What a relayed source took from elsewhere (a network camera): see [`relay`].
#[derive(Debug)]
pub enum Arrival<M> {
    /// The next message, with the wall-clock time its camera data left its own source, when the
    /// sender stamped it (latency then spans the network; otherwise it counts from arrival).
    Message(M, Option<i64>),
    /// The stream ended after `count` messages; `cut` when it was cut short where it was made.
    End {
        /// Messages the sender sent.
        count: u64,
        /// Cut short upstream.
        cut: bool,
    },
    /// Nothing yet.
    Idle,
}

/// How long a relayed source waits for its next message before it looks for a stop request.
pub const RELAY_POLL: std::time::Duration = std::time::Duration::from_millis(200);

/// Runs a source whose messages come from elsewhere: sends each message `next` takes on
/// `output`, until the stream's end (whose count and `cut` flag pass on, so a loss on the way is
/// announced downstream) or a stop request; then ends every output, whatever happened, as
/// [`produce`] does. `next(wait)` waits at most `wait`.
///
/// # Errors
/// The first error of `next` or of sending, else of ending the outputs.
pub fn relay<M: Message>(
    link: &mut Link,
    output: &str,
    mut next: impl FnMut(std::time::Duration) -> eyre::Result<Arrival<M>>,
) -> eyre::Result<()> {
    produce(link, |link| match next(RELAY_POLL)? {
        Arrival::Message(msg, origin) => {
            link.set_origin(origin.unwrap_or_else(unix_now_ns));
            link.send(output, &msg)?;
            Ok(Flow::Continue)
        }
        Arrival::End { count, cut } => {
            link.at_least(output, count)?;
            if cut {
                link.mark_cut();
            }
            Ok(Flow::Stop)
        }
        Arrival::Idle => Ok(Flow::Continue),
    })
}

/// Relays neuspike's messages of type `M` that arrive on a zenoh key (a camera on another
/// machine) on `output`, as [`relay`] does: each keeps its sender's origin stamp, and the end's
/// count and `cut` flag pass on. A message that is not an `M` ends the stream with an error
/// naming the key.
///
/// # Errors
/// As [`relay`]; the remote stream's errors (silence, a sample that is not a message).
pub fn relay_remote<M: Message>(
    link: &mut Link,
    output: &str,
    remote: &mut neuspike_net::Remote,
) -> eyre::Result<()> {
    use neuspike_net::Taken;
    let key = remote.key().to_string();
    let relayed = relay(link, output, |wait| {
        Ok(match remote.next(wait)? {
            // A payload its reader refuses (a forged size, a broken column) is one malformed
            // sample: counted and dropped, unless too many are.
            Taken::Message(meta, data) => match M::from_arrow(&meta, &data) {
                Ok(m) => Arrival::Message(m, neuspike_net::remote::origin(&meta)),
                Err(e) => {
                    remote.reject(neuspike_net::RemoteError::Header {
                        key: key.clone(),
                        n: remote.received().saturating_sub(1),
                        reason: e.to_string(),
                    })?;
                    Arrival::Idle
                }
            },
            Taken::End { count, cut } => Arrival::End { count, cut },
            Taken::Idle => Arrival::Idle,
        })
    });
    tracing::info!(
        key,
        received = remote.received(),
        lost = remote.missing(),
        refused = remote.refused(),
        foreign = remote.foreign(),
        malformed = remote.malformed(),
        restarts = remote.restarts(),
        "the remote stream ended"
    );
    relayed
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
            .run(|node, events| {
                let mut out = Link::new(node, events)?;
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
            .run(|node, events| {
                let mut out = Link::new(node, events)?;
                out.declare::<Frame>("f");
                let mut n = 0;
                let r = produce(&mut out, |out| {
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
                // Its marker says the stream was cut short.
                assert!(out.is_cut());
                Ok(())
            })
            .expect("run");
        assert_eq!(output_ids(&sent), ["f", "f", "f"]);
        assert_eq!(payload_len(&sent[2]), 0, "ended after the error");
    }

    #[test]
    fn a_marker_says_whether_its_stream_was_cut_short() {
        use neuspike_schemas::{MetaExt, is_end_of_stream};
        let whole = end_marker(7, false);
        let cut = end_marker(7, true);
        assert_eq!(
            (is_end_of_stream(&whole), is_end_of_stream(&cut)),
            (Some(7), Some(7))
        );
        assert!(!whole.flag(CUT) && cut.flag(CUT));
    }
}
