//! `--method auto`'s policy file (`Policy::from_yaml`): any text gives a policy or an error,
//! never a panic; a policy that reads chooses only methods it names, and reads back as written.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::policy::policy(data));
