//! The message type of every port of every stage, by the port's id: what a graph needs declared
//! (`input_types`, `output_types`) and checks its edges against, known without making the stage.

use neuspike_schemas::RepresentationKind;
use neuspike_stage::MsgType;

/// Which side of a node a port is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// An input.
    Input,
    /// An output.
    Output,
}

/// The type of port `port` on `side` of stage `kind` ([`crate::STAGES`]); `None` for a port the
/// stage does not have.
pub fn port_type(kind: &str, side: Side, port: &str) -> Option<MsgType> {
    let representation = RepresentationKind::ALL.iter().any(|k| k.name() == port);
    match (kind, side, port) {
        ("spike-source", Side::Output, "spikes") => Some(MsgType::SpikeChunk),
        ("spike-source", Side::Output, "ground_truth") => Some(MsgType::Frame),
        ("event-source", Side::Output, "events") => Some(MsgType::EventBatch),
        ("align", Side::Input, "spikes") => Some(MsgType::SpikeChunk),
        ("align", _, "events") => Some(MsgType::EventBatch),
        ("align", Side::Output, "windows") => Some(MsgType::AlignedWindow),
        ("represent", Side::Input, "windows") => Some(MsgType::AlignedWindow),
        ("represent", Side::Output, _) if representation => Some(MsgType::Representation),
        ("infer", Side::Input, "events") => Some(MsgType::EventBatch),
        ("infer", Side::Input, "windows") => Some(MsgType::AlignedWindow),
        ("infer", Side::Input, "representation") => Some(MsgType::Representation),
        ("infer", Side::Input, _) if representation => Some(MsgType::Representation),
        ("infer", Side::Output, "frames") => Some(MsgType::Frame),
        ("sink", Side::Input, _) => Some(MsgType::Frame),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stage_port_has_its_type_and_no_other_port_has_one() {
        assert_eq!(
            port_type("align", Side::Output, "events"),
            Some(MsgType::EventBatch)
        );
        assert_eq!(
            port_type("represent", Side::Output, "tfp"),
            Some(MsgType::Representation)
        );
        assert_eq!(port_type("represent", Side::Output, "frames"), None);
        assert_eq!(
            port_type("infer", Side::Input, "spike_repr"),
            Some(MsgType::Representation)
        );
        assert_eq!(
            port_type("sink", Side::Input, "anything"),
            Some(MsgType::Frame)
        );
        assert_eq!(port_type("sink", Side::Output, "frames"), None);
        assert_eq!(port_type("spike-source", Side::Input, "spikes"), None);
    }
}
