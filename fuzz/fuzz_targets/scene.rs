//! Scene YAML (`Scene::from_yaml_str`), what `--scene FILE` and a dataset's scenes read: any text
//! gives a scene or an error, never a panic; a scene that builds renders a small view at its
//! start and later, every pixel finite and non-negative.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::scene::scene(data));
