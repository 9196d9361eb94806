//! The format sniffer: any prefix and length gives a format or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::formats::sniff(data));
