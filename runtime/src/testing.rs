//! Canned inputs for driving a node's `run` loop in tests, without a daemon
//! (through `DoraNode::init_testing`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One output message as the testing harness records it (JSON: `id`, `data`, metadata).
pub use dora_node_api::integration_testing::OutputJson;
use dora_node_api::integration_testing::integration_testing_format::{
    IncomingEvent, InputData, IntegrationTestInput, TimedIncomingEvent,
};
use dora_node_api::integration_testing::{
    TestingInput, TestingOptions, TestingOutput, drain_outputs, output_channel,
};
use dora_node_api::{DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_schemas::arrow;
use neuspike_schemas::arrow::array::{ArrayRef, RecordBatch};
use neuspike_schemas::arrow::datatypes::{Field, Schema};

use neuspike_schemas::{Message, Meta, end_of_stream};

use crate::metadata::meta_to_dora;

/// A scripted sequence of input events; payloads are written as Arrow IPC files under `dir`.
pub struct CannedInputs {
    dir: PathBuf,
    events: Vec<TimedIncomingEvent>,
}

impl CannedInputs {
    /// An empty script writing its payload files under `dir`.
    pub fn new(dir: &Path) -> Self {
        CannedInputs {
            dir: dir.to_path_buf(),
            events: Vec::new(),
        }
    }

    fn time(&self) -> f64 {
        self.events.len() as f64 * 1e-3
    }

    fn push_payload(&mut self, input: &str, meta: Meta, data: ArrayRef) -> eyre::Result<()> {
        let path = self.dir.join(format!("input-{}.arrow", self.events.len()));
        let schema = Arc::new(Schema::new(vec![Field::new(
            "data",
            data.data_type().clone(),
            true,
        )]));
        let batch = RecordBatch::try_new(schema.clone(), vec![data])?;
        let file = std::fs::File::create(&path)
            .wrap_err_with(|| format!("cannot create {}", path.display()))?;
        let mut w = arrow::ipc::writer::FileWriter::try_new(file, &schema)?;
        w.write(&batch)?;
        w.finish()?;
        let time_offset_secs = self.time();
        self.events.push(TimedIncomingEvent {
            time_offset_secs,
            event: IncomingEvent::Input {
                id: input.to_string().into(),
                metadata: Some(meta_to_dora(&meta)),
                data: Some(Box::new(InputData::ArrowFile {
                    path,
                    batch_index: 0,
                    column: Some("data".into()),
                })),
            },
        });
        Ok(())
    }

    /// One message on `input`.
    pub fn message<M: Message>(&mut self, input: &str, msg: &M) -> eyre::Result<()> {
        let (meta, data) = msg.to_arrow();
        self.push_payload(input, meta, data)
    }

    /// A raw payload with hand-made metadata (to test bad input).
    pub fn raw(&mut self, input: &str, meta: Meta, data: ArrayRef) -> eyre::Result<()> {
        self.push_payload(input, meta, data)
    }

    /// The end-of-stream marker of `input` after `count` messages.
    pub fn end<M: Message>(&mut self, input: &str, count: u64) -> eyre::Result<()> {
        let (meta, data) = end_of_stream::<M>(count);
        self.push_payload(input, meta, data)
    }

    /// The sender of `input` exits.
    pub fn closed(&mut self, input: &str) {
        let time_offset_secs = self.time();
        self.events.push(TimedIncomingEvent {
            time_offset_secs,
            event: IncomingEvent::InputClosed {
                id: input.to_string().into(),
            },
        });
    }

    /// Runs `f` (a node's `run` loop) on these inputs and returns what it sent, in order, as dora's
    /// testing JSON objects (`id`, `data`, `data_type`; metadata is not recorded by dora).
    pub fn run<F>(self, f: F) -> eyre::Result<Vec<OutputJson>>
    where
        F: FnOnce(DoraNode, EventStream) -> eyre::Result<()>,
    {
        let mut events = self.events;
        let t = events.len() as f64 * 1e-3;
        events.push(TimedIncomingEvent {
            time_offset_secs: t,
            event: IncomingEvent::AllInputsClosed,
        });
        let input = IntegrationTestInput::new("test-node".to_string().into(), events);
        let (tx, mut rx) = output_channel();
        let (node, stream) = DoraNode::init_testing(
            TestingInput::Input(input),
            TestingOutput::ToChannel(tx),
            TestingOptions {
                skip_output_time_offsets: true,
            },
        )?;
        f(node, stream)?;
        Ok(drain_outputs(&mut rx))
    }
}

/// The ids of the outputs, in order.
pub fn output_ids(outputs: &[OutputJson]) -> Vec<String> {
    outputs
        .iter()
        .map(|o| {
            o.get("id")
                .and_then(|v| v.as_str())
                .unwrap_or("")
                .to_string()
        })
        .collect()
}

/// The number of values in an output's payload.
pub fn payload_len(output: &OutputJson) -> usize {
    output
        .get("data")
        .and_then(|d| d.as_array())
        .map_or(0, |a| a.len())
}

/// The real recording `name` of `../shared/data/real/` (beside the repository; see its README),
/// or `None` with a printed notice when it is absent (a user's fresh clone has no `../shared`):
/// tests that need one return early then.
pub fn real_recording(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/real")
        .join(name);
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "skipped: {} is absent (real recordings live in ../shared/data/real)",
            p.display()
        );
        None
    }
}
