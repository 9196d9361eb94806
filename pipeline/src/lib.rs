//! neuspike's stages by name, and a graph run in one process.
//!
//! - [`make_stage`]: a stage (`spike-source`, `event-source`, `align`, `represent`, `infer`,
//!   `sink`) made from the arguments its node takes in a graph and the inputs and outputs the
//!   graph wires, as the node binary makes it.
//! - [`GraphChain`]: a dora graph's nodes as a [`neuspike_stage::Chain`]: the same stages, the
//!   same wiring and the same rules for order, loss and the end of a stream, without dora.
//! - [`fused_stage`]: some of a graph's nodes as one stage ([`neuspike_stage::Fused`]), which
//!   the `neuspike-fused` node runs: several stages in one process.
//! - [`derive`]: a graph as a user writes it made into the graph dora runs (port types, credit
//!   edges, `build:` and `env:`, the processes it asks for), every fault one line naming the edge.
#![deny(missing_docs)]

pub mod derive;
mod graph;
mod ports;
mod registry;

pub use graph::{
    FUSED_STAGES, GraphChain, GraphNode, MAX_GRAPH_BYTES, data_inputs, fused_port, fused_stage,
    read_graph, read_graph_text,
};
pub use ports::{Side, port_type};
pub use registry::{STAGES, make_stage, stage_kind};
