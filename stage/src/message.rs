//! A message of any of neuspike's types, as a stage takes and sends it.

use neuspike_schemas::arrow::array::ArrayRef;
use neuspike_schemas::arrow::datatypes::DataType;
use neuspike_schemas::{
    AlignedWindow, EventBatch, Frame, Message, Meta, Representation, SchemaError, SpikeChunk,
};

/// The type of a port's messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MsgType {
    /// [`SpikeChunk`].
    SpikeChunk,
    /// [`EventBatch`].
    EventBatch,
    /// [`AlignedWindow`].
    AlignedWindow,
    /// [`Representation`].
    Representation,
    /// [`Frame`].
    Frame,
}

/// A message of one of the types stages exchange.
#[derive(Clone, Debug)]
pub enum Msg {
    /// Spike planes.
    Spikes(SpikeChunk),
    /// Events.
    Events(EventBatch),
    /// An aligned window.
    Window(AlignedWindow),
    /// A representation of a window.
    Representation(Representation),
    /// A frame.
    Frame(Frame),
}

/// A message of another type than the one asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("a {found} message where a {expected} was expected")]
pub struct WrongType {
    /// The type asked for.
    pub expected: MsgType,
    /// The message's.
    pub found: MsgType,
}

impl std::fmt::Display for MsgType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl MsgType {
    /// The type's name in the messages' contract (`Frame`, `SpikeChunk`, ...).
    pub fn name(self) -> &'static str {
        match self {
            MsgType::SpikeChunk => "SpikeChunk",
            MsgType::EventBatch => "EventBatch",
            MsgType::AlignedWindow => "AlignedWindow",
            MsgType::Representation => "Representation",
            MsgType::Frame => "Frame",
        }
    }

    /// The type's URN in the graphs (`neuspike/messages/v1/Frame`, ...).
    pub fn urn(self) -> &'static str {
        match self {
            MsgType::SpikeChunk => SpikeChunk::TYPE_URN,
            MsgType::EventBatch => EventBatch::TYPE_URN,
            MsgType::AlignedWindow => AlignedWindow::TYPE_URN,
            MsgType::Representation => Representation::TYPE_URN,
            MsgType::Frame => Frame::TYPE_URN,
        }
    }

    /// The type whose URN is `urn`.
    pub fn from_urn(urn: &str) -> Option<MsgType> {
        [
            MsgType::SpikeChunk,
            MsgType::EventBatch,
            MsgType::AlignedWindow,
            MsgType::Representation,
            MsgType::Frame,
        ]
        .into_iter()
        .find(|t| t.urn() == urn)
    }

    /// The Arrow type of its payload.
    pub fn data_type(self) -> DataType {
        match self {
            MsgType::SpikeChunk => SpikeChunk::data_type(),
            MsgType::EventBatch => EventBatch::data_type(),
            MsgType::AlignedWindow => AlignedWindow::data_type(),
            MsgType::Representation => Representation::data_type(),
            MsgType::Frame => Frame::data_type(),
        }
    }

    /// Decodes a message of this type from its header and Arrow payload.
    ///
    /// # Errors
    /// The header or the payload is not a message of this type.
    pub fn from_arrow(self, meta: &Meta, data: &ArrayRef) -> Result<Msg, SchemaError> {
        Ok(match self {
            MsgType::SpikeChunk => Msg::Spikes(SpikeChunk::from_arrow(meta, data)?),
            MsgType::EventBatch => Msg::Events(EventBatch::from_arrow(meta, data)?),
            MsgType::AlignedWindow => Msg::Window(AlignedWindow::from_arrow(meta, data)?),
            MsgType::Representation => Msg::Representation(Representation::from_arrow(meta, data)?),
            MsgType::Frame => Msg::Frame(Frame::from_arrow(meta, data)?),
        })
    }
}

impl Msg {
    /// Its type.
    pub fn ty(&self) -> MsgType {
        match self {
            Msg::Spikes(_) => MsgType::SpikeChunk,
            Msg::Events(_) => MsgType::EventBatch,
            Msg::Window(_) => MsgType::AlignedWindow,
            Msg::Representation(_) => MsgType::Representation,
            Msg::Frame(_) => MsgType::Frame,
        }
    }

    /// Its sequence number.
    pub fn seq(&self) -> u64 {
        match self {
            Msg::Spikes(m) => m.seq,
            Msg::Events(m) => m.seq,
            Msg::Window(m) => m.seq(),
            Msg::Representation(m) => m.seq,
            Msg::Frame(m) => m.seq,
        }
    }

    /// Its header and Arrow payload.
    pub fn to_arrow(&self) -> (Meta, ArrayRef) {
        match self {
            Msg::Spikes(m) => m.to_arrow(),
            Msg::Events(m) => m.to_arrow(),
            Msg::Window(m) => m.to_arrow(),
            Msg::Representation(m) => m.to_arrow(),
            Msg::Frame(m) => m.to_arrow(),
        }
    }
}

macro_rules! typed {
    ($variant:ident, $ty:ident) => {
        impl From<$ty> for Msg {
            fn from(m: $ty) -> Msg {
                Msg::$variant(m)
            }
        }

        impl TryFrom<Msg> for $ty {
            type Error = WrongType;
            fn try_from(m: Msg) -> Result<$ty, WrongType> {
                match m {
                    Msg::$variant(m) => Ok(m),
                    other => Err(WrongType {
                        expected: MsgType::$ty,
                        found: other.ty(),
                    }),
                }
            }
        }
    };
}

typed!(Spikes, SpikeChunk);
typed!(Events, EventBatch);
typed!(Window, AlignedWindow);
typed!(Representation, Representation);
typed!(Frame, Frame);

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::FrameKind;

    #[test]
    fn a_message_goes_through_arrow_and_back_as_its_own_type_only() {
        let f = Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: 5,
            compute_ns: 1,
            chosen: None,
            budget_ns: None,
            seq: 3,
            data: ndarray::Array2::from_elem((2, 3), 0.25),
        };
        let m = Msg::from(f.clone());
        assert_eq!((m.ty(), m.seq()), (MsgType::Frame, 3));
        let (meta, data) = m.to_arrow();
        let back = MsgType::Frame.from_arrow(&meta, &data).expect("a frame");
        assert_eq!(Frame::try_from(back).expect("frame").data, f.data);
        assert!(MsgType::SpikeChunk.from_arrow(&meta, &data).is_err());
        let e = SpikeChunk::try_from(Msg::from(f)).expect_err("not spikes");
        assert_eq!(
            e.to_string(),
            "a Frame message where a SpikeChunk was expected"
        );
        for t in [MsgType::SpikeChunk, MsgType::Frame, MsgType::AlignedWindow] {
            assert_eq!(MsgType::from_urn(t.urn()), Some(t));
        }
        assert_eq!(MsgType::from_urn("neuspike/messages/v1/Nothing"), None);
    }
}
