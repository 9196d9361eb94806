//! The format sniffer: any prefix and length gives a format or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::sniff::sniff_bytes;

fuzz_target!(|data: &[u8]| {
    let len = data.len() as u64;
    if let Err(e) = sniff_bytes(data, len, std::path::Path::new("fuzz")) {
        let _ = e.to_string();
    }
    // A prefix of a longer file.
    let _ = sniff_bytes(
        data,
        len.saturating_mul(3).saturating_add(7),
        std::path::Path::new("fuzz"),
    );
});
