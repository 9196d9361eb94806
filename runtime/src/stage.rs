//! The dora driver of a stage: the stage as a node, one process, its messages Arrow on dora's
//! links (the in-process driver is `neuspike_stage::Chain`).

use dora_node_api::{DoraNode, EventStream};
use eyre::eyre;
use neuspike_schemas::Parameter;
use neuspike_schemas::meta::ORIGIN_UNIX_NS;
use neuspike_stage::{Msg, Outbox, Stage, Tallies, Tally};

use crate::{Inputs, Link, Received, receive};

/// Runs `stage` as the node `node`: its outputs declared with their message types, every message
/// of its inputs decoded by its port's type and handed over in sequence order with the receive
/// loop's accounting ([`receive`]), what it sends sent through the node's [`Link`] (credits,
/// sequence numbers, origin stamps), and, once its inputs ended, [`Stage::finish`] and every
/// output's end-of-stream marker. A source (no inputs) steps until it stops or a stop is asked
/// for; its outputs end whatever happened, cut short after an error. A stage with inputs is
/// finished after its own failure too (a sink still writes its summary), and its failure comes
/// first in the error.
///
/// # Errors
/// A message that is not of its input's type (named with the stage and the input), the stage's
/// first error, or the link's.
pub fn run_stage<S: Stage + ?Sized>(
    node: DoraNode,
    events: EventStream,
    stage: &mut S,
) -> eyre::Result<()> {
    let mut link = Link::new(node, events)?;
    for p in stage.outputs() {
        link.declare_as(&p.id, p.ty.data_type());
    }
    let ports = stage.inputs();
    let mut out = Outbox::new();
    if ports.is_empty() {
        return produce(&mut link, stage, &mut out);
    }
    let name = stage.name().to_string();
    let mut inputs = Inputs::new(ports.iter().map(|p| p.id.as_str()));
    let received = receive(&mut link, &mut inputs, |link, msg| {
        let flow = match msg {
            Received::Message { input, meta, data } => {
                let ty = ports
                    .iter()
                    .find(|p| p.id == input)
                    .map(|p| p.ty)
                    .ok_or_else(|| eyre!("{name}: input `{input}` is not one it reads"))?;
                let msg = ty
                    .from_arrow(meta, data)
                    .map_err(|e| eyre!("{name}: input `{input}`: {e}"))?;
                out.set_incoming_origin(match meta.get(ORIGIN_UNIX_NS) {
                    Some(Parameter::Integer(t)) => Some(*t),
                    _ => None,
                });
                stage.on_message(input, msg, &mut out)?
            }
            Received::End { input, count } => stage.on_end(input, count, &mut out)?,
        };
        flush(link, &mut out)?;
        Ok(flow)
    });
    let tallies = Tallies(
        inputs
            .iter()
            .map(|(id, s)| (id.to_string(), Tally::from_seq(&s.seq, s.ended, s.broken)))
            .collect(),
    );
    // The stage is finished whatever happened: after its own failure too, so that what it keeps
    // (a sink's summary: the counts so far and the failure) is still written. What it sent
    // before a failure still goes out, and every output ends (cut short after a failure), so
    // that the nodes after it keep what they took whole.
    let finished = stage.finish(&tallies, &mut out);
    if received.is_err() || finished.is_err() {
        out.mark_cut();
    }
    let flushed = flush(&mut link, &mut out);
    let ended = link.end_all();
    let finished = match (received, finished) {
        (Err(first), Err(then)) => Err(eyre!("{first:#}; then, finishing: {then:#}")),
        (received, finished) => received.and(finished),
    };
    finished.and(flushed).and(ended)
}

/// A source's loop: steps until it stops, a stop is asked for or nobody is left to take what it
/// makes; then finishes it and ends every output, whatever happened (cut short after an error),
/// so that the messages already sent stay a whole stream.
fn produce<S: Stage + ?Sized>(
    link: &mut Link,
    stage: &mut S,
    out: &mut Outbox,
) -> eyre::Result<()> {
    let mut state = (stage, out);
    crate::link::produce_with(
        link,
        &mut state,
        |link, (stage, out)| {
            let r = stage.step(out);
            flush(link, out)?;
            r
        },
        |link, (stage, out)| {
            stage.finish(&Tallies::default(), out)?;
            flush(link, out)
        },
    )
}

/// Sends what the stage put in `out`.
fn flush(link: &mut Link, out: &mut Outbox) -> eyre::Result<()> {
    if out.take_cut() {
        link.mark_cut();
    }
    for sent in out.take_sent() {
        if let Some(origin) = sent.origin_unix_ns {
            link.set_origin(origin);
        }
        match &sent.msg {
            Msg::Spikes(m) => link.send(&sent.output, m)?,
            Msg::Events(m) => link.send(&sent.output, m)?,
            Msg::Window(m) => link.send(&sent.output, m)?,
            Msg::Representation(m) => link.send(&sent.output, m)?,
            Msg::Frame(m) => link.send(&sent.output, m)?,
        }
    }
    for (output, count) in out.take_at_least() {
        link.at_least(&output, count)?;
    }
    Ok(())
}
