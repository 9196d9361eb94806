//! What the `ros2_cdr` fuzz target checks, as a plain function:
//! `stages/event-camera/tests/corpus.rs` replays the committed corpus through it without
//! libFuzzer.

use neuspike_event_camera::ros2::PacketDecoder;
use neuspike_net::ros2::{parse_attachment, parse_event_packet, parse_image};

/// ROS 2 samples as they arrive over rmw_zenoh (an `Image`, an `EventPacket`, an attachment):
/// any bytes parse or give an error, never a panic; a packet that parses goes through the
/// source's packet decoder split in two, and its batches hold valid events that tile time.
pub fn ros2_cdr(data: &[u8]) {
    let _ = parse_attachment(data);
    if let Ok(img) = parse_image(data) {
        assert_eq!(
            img.data.len() as u64,
            u64::from(img.height) * u64::from(img.step)
        );
    }
    let Ok(packet) = parse_event_packet(data) else {
        return;
    };
    let mut decoder = PacketDecoder::new("/fuzz");
    let cut = usize::from(data.first().copied().unwrap_or(0)) * 2;
    let cut = cut.min(packet.events.len());
    let mut first = packet.clone();
    first.events.truncate(cut);
    let mut second = packet.clone();
    second.events.drain(..cut);
    second.seq = second.seq.wrapping_add(1);
    let mut end = None;
    for p in [first, second] {
        match decoder.packet(&p) {
            Ok(batch) => {
                batch.validate("fuzz").expect("a batch holds valid events");
                if let Some(e) = end {
                    assert_eq!(batch.t_start_ns, e, "batches tile time");
                }
                end = Some(batch.t_end_ns);
            }
            Err(e) => {
                let _ = e.to_string();
                return;
            }
        }
    }
    if let Some(last) = decoder.flush() {
        last.validate("fuzz").expect("the held events are valid");
    }
}
