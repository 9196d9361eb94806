//! The dora node around [`neuspike_example_node::tone_map`]: input `representation`
//! (Representation), output `frames` (Frame), exactly like neuspike's infer node, so a graph puts
//! it in infer's place (`examples/rust-node/graph.yml`). neuspike's runtime does the rest: inputs
//! in order, losses counted, credits returned, end-of-stream markers passed on.

use dora_node_api::{DoraNode, EventStream};
use neuspike_example_node::{Settings, tone_map};
use neuspike_runtime::{Flow, Inputs, Link, Received, receive};
use neuspike_schemas::{Frame, Message, Representation};

#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-example-node",
    about = "Tone-maps TFP representations"
)]
struct Args {
    #[command(flatten)]
    settings: Settings,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("example-node")?;
    args.settings.check()?;
    let (node, events) = neuspike_runtime::init_node()?;
    run(node, events, &args.settings)
}

/// Sends the frame of every representation, in order, then the end-of-stream marker.
fn run(node: DoraNode, events: EventStream, settings: &Settings) -> eyre::Result<()> {
    let mut link = Link::new(node, events)?;
    link.declare::<Frame>("frames");
    let mut inputs = Inputs::new(["representation"]);
    receive(&mut link, &mut inputs, |link, msg| {
        if let Received::Message { meta, data, .. } = msg {
            let rep = Representation::from_arrow(meta, data)?;
            link.send("frames", &tone_map(&rep, settings.gamma)?)?;
        }
        Ok(Flow::Continue)
    })?;
    // A window lost upstream is announced downstream too.
    link.at_least("frames", inputs.announced())?;
    link.end_all()
}

#[cfg(test)]
mod node_tests {
    use super::*;
    use neuspike_runtime::testing::{CannedInputs, output_ids, payload_len};
    use neuspike_schemas::RepresentationKind;

    #[test]
    fn every_representation_becomes_a_frame_and_the_stream_ends() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut c = CannedInputs::new(dir.path());
        for seq in 0..3 {
            let rep = Representation {
                kind: RepresentationKind::Tfp,
                t_ref_ns: 1_000 * seq as i64,
                seq,
                params: Default::default(),
                data: ndarray::Array3::from_elem((1, 4, 5), 0.25),
            };
            c.message("representation", &rep).expect("message");
        }
        c.end::<Representation>("representation", 3).expect("end");
        let sent = c
            .run(|node, events| run(node, events, &Settings { gamma: 0.5 }))
            .expect("run");
        assert_eq!(output_ids(&sent), ["frames", "frames", "frames", "frames"]);
        assert_eq!(payload_len(&sent[0]), 20);
        assert_eq!(payload_len(&sent[3]), 0, "the end-of-stream marker");
    }
}
