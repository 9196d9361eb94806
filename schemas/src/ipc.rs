//! A message as bytes, for links that are not dora's: one Arrow IPC stream holding the payload
//! as the single column `data` of one record batch, and the header in the schema's metadata.
//! What `neuspike-publish` puts on zenoh, and what a source reading a network camera takes.
//!
//! The header keeps its types: each value is stored as text with a one-letter type prefix
//! (`b:true`, `i:-3`, `f:0.5`, `s:text`; `o:` describes a value of another kind); the key `neuspike.type` names the message type
//! ([`crate::Message::TYPE_URN`]). Reading checks every part and fails with an error naming it;
//! it never panics and allocates at most what the bytes hold (Arrow's reader checks each buffer
//! against the body it came in).

use std::collections::HashMap;
use std::sync::Arc;

use arrow::array::{Array, ArrayRef, RecordBatch};
use arrow::datatypes::{Field, Schema};

use crate::meta::{Meta, Parameter};

/// The schema-metadata key of the message type.
pub const TYPE_KEY: &str = "neuspike.type";

/// Why bytes are not a message.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IpcError {
    /// Not an Arrow IPC stream, or a damaged one.
    #[error("not an Arrow IPC message: {0}")]
    Arrow(String),
    /// The stream does not hold exactly one batch of one column.
    #[error("an Arrow IPC message holds one batch of one column `data`; found {0}")]
    Shape(String),
    /// A header value without a known type prefix.
    #[error("header key `{key}`: `{value}` is not a typed value (b:, i:, f:, s:, o:)")]
    Header {
        /// The key.
        key: String,
        /// What was found.
        value: String,
    },
    /// The message type is missing.
    #[error("the header has no `{TYPE_KEY}`")]
    NoType,
}

fn typed(p: &Parameter) -> String {
    match p {
        Parameter::Bool(b) => format!("b:{b}"),
        Parameter::Integer(i) => format!("i:{i}"),
        // `{:?}` keeps every bit of an f64 (shortest round trip), `inf` and `NaN` included.
        Parameter::Float(f) => format!("f:{f:?}"),
        Parameter::String(s) => format!("s:{s}"),
        // Kept as its description: no neuspike message has one.
        Parameter::Other(s) => format!("o:{s}"),
    }
}

fn untyped(key: &str, v: &str) -> Result<Parameter, IpcError> {
    let bad = || IpcError::Header {
        key: key.to_string(),
        value: v.chars().take(64).collect(),
    };
    let (kind, text) = v.split_once(':').ok_or_else(bad)?;
    match kind {
        "b" => text.parse().map(Parameter::Bool).map_err(|_| bad()),
        "i" => text.parse().map(Parameter::Integer).map_err(|_| bad()),
        "f" => text.parse().map(Parameter::Float).map_err(|_| bad()),
        "s" => Ok(Parameter::String(text.to_string())),
        "o" => Ok(Parameter::Other(text.to_string())),
        _ => Err(bad()),
    }
}

/// The message of type `type_urn` with header `meta` and payload `data`, as one Arrow IPC stream.
///
/// # Errors
/// Arrow could not write it (a payload type the IPC format cannot hold).
pub fn encode(type_urn: &str, meta: &Meta, data: &ArrayRef) -> Result<Vec<u8>, IpcError> {
    let mut md: HashMap<String, String> = meta.iter().map(|(k, v)| (k.clone(), typed(v))).collect();
    md.insert(TYPE_KEY.to_string(), type_urn.to_string());
    let schema = Arc::new(
        Schema::new(vec![Field::new("data", data.data_type().clone(), true)]).with_metadata(md),
    );
    let arrow_err = |e: arrow::error::ArrowError| IpcError::Arrow(e.to_string());
    let batch = RecordBatch::try_new(schema.clone(), vec![data.clone()]).map_err(arrow_err)?;
    let mut out = Vec::with_capacity(data.get_array_memory_size() + 1024);
    let mut w = arrow::ipc::writer::StreamWriter::try_new(&mut out, &schema).map_err(arrow_err)?;
    w.write(&batch).map_err(arrow_err)?;
    w.finish().map_err(arrow_err)?;
    drop(w);
    Ok(out)
}

/// Walks the stream's framing and checks every length against the bytes that follow: Arrow's
/// reader allocates the body a message claims before it reads it.
fn check_framing(bytes: &[u8]) -> Result<(), IpcError> {
    let word = |at: usize| -> Result<u32, IpcError> {
        bytes
            .get(at..at + 4)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(u32::from_le_bytes)
            .ok_or_else(|| IpcError::Arrow(format!("the stream ends inside a length at byte {at}")))
    };
    let mut at = 0usize;
    loop {
        let mut len = word(at)?;
        at += 4;
        if len == 0xFFFF_FFFF {
            len = word(at)?;
            at += 4;
        }
        if len == 0 {
            return Ok(());
        }
        let header = bytes
            .get(at..at.saturating_add(len as usize))
            .ok_or_else(|| {
                IpcError::Arrow(format!(
                    "a message header of {len} bytes at byte {at}, {} left",
                    bytes.len() - at
                ))
            })?;
        let message = arrow::ipc::root_as_message(header)
            .map_err(|e| IpcError::Arrow(format!("a message header at byte {at}: {e}")))?;
        at += len as usize;
        let body = usize::try_from(message.bodyLength()).unwrap_or(usize::MAX);
        if body > bytes.len() - at {
            return Err(IpcError::Arrow(format!(
                "a message body of {} bytes at byte {at}, {} left",
                message.bodyLength(),
                bytes.len() - at
            )));
        }
        // Every buffer of a batch lies inside its body (Arrow's reader slices without asking).
        let batch = message
            .header_as_record_batch()
            .or_else(|| message.header_as_dictionary_batch().and_then(|d| d.data()));
        if let Some(buffers) = batch.and_then(|b| b.buffers()) {
            for b in buffers {
                let end = b.offset().checked_add(b.length());
                if b.offset() < 0 || b.length() < 0 || end.is_none_or(|e| e as u64 > body as u64) {
                    return Err(IpcError::Arrow(format!(
                        "a buffer of {} bytes at {} outside the body of {body} bytes",
                        b.length(),
                        b.offset()
                    )));
                }
            }
        }
        at += body;
    }
}

/// A message read back from [`encode`]'s bytes: its type, header and payload.
///
/// # Errors
/// The bytes are not one Arrow IPC stream of one batch with one column, or its header is not
/// typed as [`encode`] writes it.
pub fn decode(bytes: &[u8]) -> Result<(String, Meta, ArrayRef), IpcError> {
    check_framing(bytes)?;
    // Arrow's reader asserts some of what it reads (a schema's types, a bitmap's length) instead
    // of returning an error: such damage ends as an error here, silently, never as a panic of
    // the caller or a message on its terminal.
    quiet_panics();
    QUIET.with(|q| q.set(true));
    let result = std::panic::catch_unwind(|| read(bytes));
    QUIET.with(|q| q.set(false));
    result.unwrap_or_else(|_| {
        Err(IpcError::Arrow(
            "a damaged message (Arrow's reader refused it)".into(),
        ))
    })
}

thread_local! {
    /// Set while this thread decodes: a panic then is caught and turned into an error.
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Installs, once, a panic hook that stays silent for a panic caught by [`decode`] and hands
/// every other panic to the hook that was there before.
fn quiet_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
}

fn read(bytes: &[u8]) -> Result<(String, Meta, ArrayRef), IpcError> {
    let arrow_err = |e: arrow::error::ArrowError| IpcError::Arrow(e.to_string());
    let mut reader = arrow::ipc::reader::StreamReader::try_new(std::io::Cursor::new(bytes), None)
        .map_err(arrow_err)?;
    let schema = reader.schema();
    let batch = match reader.next() {
        Some(b) => b.map_err(arrow_err)?,
        None => return Err(IpcError::Shape("no batch".into())),
    };
    if reader.next().is_some() {
        return Err(IpcError::Shape("more than one batch".into()));
    }
    if batch.num_columns() != 1 || schema.field(0).name() != "data" {
        return Err(IpcError::Shape(format!("{} columns", batch.num_columns())));
    }
    let mut urn = None;
    let mut meta = Meta::new();
    for (k, v) in schema.metadata() {
        if k == TYPE_KEY {
            urn = Some(v.clone());
        } else {
            meta.insert(k.clone(), untyped(k, v)?);
        }
    }
    let urn = urn.ok_or(IpcError::NoType)?;
    Ok((urn, meta, batch.column(0).clone()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Frame, FrameKind, Message, SpikeChunk};

    #[test]
    fn a_message_comes_back_whole_with_its_typed_header() {
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: -5,
            compute_ns: 7,
            chosen: None,
            budget_ns: None,
            seq: 3,
            data: ndarray::Array2::from_shape_fn((2, 3), |(r, c)| (r * 3 + c) as f32 / 8.0),
        };
        let (mut meta, data) = frame.to_arrow();
        meta.insert("x.flag".into(), Parameter::Bool(true));
        meta.insert("x.gain".into(), Parameter::Float(0.1 + 0.2));
        let bytes = encode(Frame::TYPE_URN, &meta, &data).expect("encode");
        let (urn, back_meta, back_data) = decode(&bytes).expect("decode");
        assert_eq!(urn, Frame::TYPE_URN);
        assert_eq!(back_meta, meta);
        assert_eq!(
            Frame::from_arrow(&back_meta, &back_data).expect("frame"),
            frame
        );

        let chunk = SpikeChunk {
            width: 9,
            height: 2,
            first_plane: 40,
            n_planes: 2,
            t_first_ns: 2_000_000,
            plane_period_ns: 50_000,
            seq: 2,
            bits: vec![0xA5; 6],
            lum_per_rate: None,
        };
        let (meta, data) = chunk.to_arrow();
        let (_, m, d) =
            decode(&encode(SpikeChunk::TYPE_URN, &meta, &data).expect("enc")).expect("dec");
        assert_eq!(SpikeChunk::from_arrow(&m, &d).expect("chunk"), chunk);
    }

    #[test]
    fn damaged_bytes_are_an_error_never_a_panic() {
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: 0,
            compute_ns: 0,
            chosen: None,
            budget_ns: None,
            seq: 0,
            data: ndarray::Array2::zeros((4, 4)),
        };
        let (meta, data) = frame.to_arrow();
        let bytes = encode(Frame::TYPE_URN, &meta, &data).expect("encode");
        assert!(decode(&[]).is_err());
        // A body claimed far beyond the bytes is refused before anything is allocated for it.
        let mut huge = bytes.clone();
        let meta_len = u32::from_le_bytes(huge[4..8].try_into().expect("4 bytes")) as usize;
        let schema_end = 8 + meta_len;
        let batch_meta = u32::from_le_bytes(
            huge[schema_end + 4..schema_end + 8]
                .try_into()
                .expect("4 bytes"),
        ) as usize;
        let header = &huge[schema_end + 8..schema_end + 8 + batch_meta];
        let body = arrow::ipc::root_as_message(header)
            .expect("header")
            .bodyLength();
        let pos = header
            .windows(8)
            .position(|w| w == body.to_le_bytes())
            .expect("bodyLength in the header");
        huge[schema_end + 8 + pos..schema_end + 16 + pos]
            .copy_from_slice(&(1i64 << 40).to_le_bytes());
        let e = decode(&huge).expect_err("a 1 TiB body").to_string();
        assert!(e.contains("body of 1099511627776 bytes"), "{e}");
        assert!(decode(b"not arrow at all").is_err());
        for cut in [1, 8, bytes.len() / 2, bytes.len() - 1] {
            let _ = decode(&bytes[..cut]);
        }
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        for _ in 0..2000 {
            let mut b = bytes.clone();
            for _ in 0..4 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let i = (x % b.len() as u64) as usize;
                b[i] = (x >> 32) as u8;
            }
            let _ = decode(&b);
        }
        assert_eq!(
            untyped("k", "q:1"),
            Err(IpcError::Header {
                key: "k".into(),
                value: "q:1".into()
            })
        );
    }
}
