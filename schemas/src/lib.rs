//! Every message the neuspike nodes speak, defined once.
//!
//! A message travels over dora as one Arrow array (the payload) plus metadata parameters (the
//! header: sizes, clocks, sequence numbers). This crate owns both halves for each message type,
//! the conversion to and from Rust types (with errors that name the key, the expected type and
//! the value found), and the conversion between the wire layout and `ndarray` views that kernels
//! use. It does not depend on dora: the node runtime (`neuspike-runtime`) moves headers in and
//! out of dora's metadata, so file tools read and write messages without linking dora.
//!
//! | message | payload | header keys |
//! |---|---|---|
//! | [`SpikeChunk`] | `UInt8`: N bit-packed planes | width, height, first_plane, n_planes, t_first_ns, plane_period_ns, seq |
//! | [`EventBatch`] | `Struct{t_ns Int64, x UInt16, y UInt16, polarity Int8}` | width, height, t_start_ns, t_end_ns, seq |
//! | [`AlignedWindow`] | `Struct{spikes LargeBinary, events LargeList<Event>}` (one row) | the spike header + t_ref_ns, ref_plane, t_start_ns, t_end_ns |
//! | [`Representation`] | `Float32`: `[C, H, W]` | kind, channels, height, width, t_ref_ns, seq, `param.*` |
//! | [`Frame`] | `Float32`: `[H, W]` luminance in [0, 1] | kind, method, width, height, t_ref_ns, compute_ns, seq |
//!
//! Every output stream ends with an end-of-stream marker ([`end_of_stream`]): an empty payload of
//! the stream's type with `eos = true` and `count` = the number of messages sent before it. With
//! the sequence number on every message, a receiver ([`SeqTracker`]) can tell exactly how many
//! messages went missing, including at the tail of a stream.
//!
//! The dora type files for `output_types`/`input_types` live in `schemas/types/neuspike/` and
//! describe the same layouts (URN prefix `neuspike/messages/v1`).
#![deny(missing_docs)]

mod credit;
mod events;
mod frame;
pub mod ipc;
mod kind;
pub mod limits;
pub mod meta;
mod spikes;
mod stream;
mod window;

pub use credit::{Credit, HELLO};
pub use events::{Event, EventBatch};
pub use frame::{Frame, FrameKind, Representation};
pub use kind::{RepresentationKind, UnknownKind};
pub use meta::{Meta, MetaExt, Parameter, SchemaError};
pub use spikes::{SpikeChunk, bytes_per_plane, fired_pixels, pack_planes, unpack_planes_into};
pub use stream::{
    MAX_SEQ_JUMP, RESYNC_AFTER, SeqStatus, SeqTracker, end_of_stream, end_of_stream_header,
    is_end_of_stream,
};
pub use window::{AlignedWindow, Central};

/// Re-exported so that nodes name the exact Arrow dora uses.
pub use arrow;

use arrow::array::ArrayRef;

/// A message type with an Arrow payload and a metadata header.
pub trait Message: Sized {
    /// The dora type URN declared in `schemas/types` (used in `output_types`).
    const TYPE_URN: &'static str;
    /// The Arrow data type of the payload.
    fn data_type() -> arrow::datatypes::DataType;
    /// Encodes the message: header and payload.
    fn to_arrow(&self) -> (Meta, ArrayRef);
    /// Decodes a message, checking the header and payload against each other.
    fn from_arrow(meta: &Meta, data: &ArrayRef) -> Result<Self, SchemaError>;
}
