//! Graph YAML, what `neuspike run`, `neuspike graph` and `--in-process` read (`derive`,
//! `GraphChain::from_yaml`): any text gives a graph or a one-line error, never a panic; a graph
//! that derives derives again to itself.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::graph::graph(data));
