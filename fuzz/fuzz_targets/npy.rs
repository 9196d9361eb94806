//! NumPy `.npy` headers (`npy::parse_header`): any bytes give a header or an error, never a panic,
//! and a parsed header's data offset is where its bytes end.
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::npy::parse_header;

fuzz_target!(|data: &[u8]| {
    let mut reader = data;
    match parse_header(&mut reader, std::path::Path::new("fuzz.npy")) {
        Ok(h) => assert_eq!(h.data_offset as usize, data.len() - reader.len()),
        Err(e) => {
            let _ = e.to_string();
        }
    }
});
