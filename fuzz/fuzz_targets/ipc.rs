//! neuspike's messages as Arrow IPC bytes (what the sources take off zenoh): any bytes give a
//! message or an error, never a panic, and decoding allocates no more than the bytes hold. A
//! decoded message of any type is then checked by that type's reader, which must refuse or
//! accept it without panicking, and an accepted message encodes back to bytes that decode.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::ipc::ipc(data));
