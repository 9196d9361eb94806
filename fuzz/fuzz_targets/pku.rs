//! PKU spike `.dat`: whole planes are delivered in order, a partial last plane is reported, and
//! nothing panics, for small geometries chosen by the first bytes (head columns included).
#![no_main]
use libfuzzer_sys::fuzz_target;
use neuspike_formats::pku::{PkuGeometry, PkuOptions, PkuReader};

fuzz_target!(|data: &[u8]| {
    let [w, h, flags, rest @ ..] = data else {
        return;
    };
    let g = PkuGeometry {
        width: usize::from(*w % 64) + 1,
        height: usize::from(*h % 16) + 1,
        head_columns: if flags & 1 != 0 { 16 } else { 0 },
    };
    let opts = PkuOptions {
        geometry: g,
        ..PkuOptions::default()
    };
    let Ok(mut r) = PkuReader::from_reader(rest, "fuzz.dat", &opts) else {
        return;
    };
    let n = usize::from(flags >> 1) + 1;
    let mut planes = 0u64;
    loop {
        match r.next_chunk(n) {
            Ok(Some(c)) => {
                assert_eq!(c.bits.len(), c.n_planes * g.plane_bytes());
                assert_eq!(c.first_plane, planes);
                planes += c.n_planes as u64;
            }
            Ok(None) => break,
            Err(e) => {
                let _ = e.to_string();
                break;
            }
        }
    }
    assert_eq!(planes, (rest.len() / g.stored_plane_bytes()) as u64);
});
