//! What the `ipc` fuzz target checks, as a plain function: `schemas/tests/corpus.rs` replays the
//! committed corpus through it without libFuzzer.

use neuspike_schemas::{
    AlignedWindow, Credit, EventBatch, Frame, Message, Representation, SpikeChunk, ipc,
};

fn check<M: Message>(
    meta: &neuspike_schemas::Meta,
    data: &neuspike_schemas::arrow::array::ArrayRef,
) {
    if let Ok(m) = M::from_arrow(meta, data) {
        let (meta, data) = m.to_arrow();
        let bytes = ipc::encode(M::TYPE_URN, &meta, &data).expect("a message encodes");
        let (urn, meta2, data2) = ipc::decode(&bytes).expect("its own bytes decode");
        assert_eq!(urn, M::TYPE_URN);
        assert!(M::from_arrow(&meta2, &data2).is_ok(), "it reads back");
    }
}

/// neuspike's messages as Arrow IPC bytes: any bytes give a message or an error, never a panic; a
/// message of any type is refused or accepted by its reader, and an accepted one encodes back to
/// bytes that decode.
pub fn ipc(data: &[u8]) {
    let Ok((urn, meta, array)) = ipc::decode(data) else {
        return;
    };
    match urn.as_str() {
        Frame::TYPE_URN => check::<Frame>(&meta, &array),
        Representation::TYPE_URN => check::<Representation>(&meta, &array),
        SpikeChunk::TYPE_URN => check::<SpikeChunk>(&meta, &array),
        EventBatch::TYPE_URN => check::<EventBatch>(&meta, &array),
        AlignedWindow::TYPE_URN => check::<AlignedWindow>(&meta, &array),
        _ => check::<Credit>(&meta, &array),
    }
}
