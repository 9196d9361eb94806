//! Times the EVT 2.0 and EVT 3.0 readers on the same events, in alternating passes from memory,
//! and prints each reader's best and median pass. On a shared, noisy machine the best pass is
//! the figure least disturbed by other work, and EVT 2.0 in the same run is the baseline.
//!
//! The EVT 3.0 bytes are the EVT 2.0 file's events re-encoded by our writer, twice, as in
//! `cargo bench -p neuspike-formats --bench bench_read`: in its shortest words, and with every
//! run of two or more events in one whole 32-column vector group
//! (`Evt3Writer::with_full_vector_groups`), a stream heavy with vectors.
//!
//! `cargo run --release --example read_passes -- [FILE.raw] [PASSES]`: FILE is a 640x480 EVT 2.0
//! recording, read at that resolution (default: the shared real one), 200 passes of each.

use std::time::Instant;

use eyre::WrapErr;
use neuspike_formats::raw::{Evt3Writer, RawReader};
use neuspike_formats::{EventBatch, EventReader, ReadOptions, Resolution, read_all};

/// Events asked of a reader at a time.
const CHUNK: usize = 65_536;

/// Reads all of `bytes`; returns the events and the pass's seconds.
fn pass(bytes: &[u8], opts: &ReadOptions) -> eyre::Result<(usize, f64)> {
    let start = Instant::now();
    let mut r = RawReader::from_reader(std::hint::black_box(bytes), "memory", opts)?;
    let mut b = EventBatch::default();
    let mut n = 0;
    loop {
        b.truncate(0);
        match r.read_into(&mut b, CHUNK)? {
            0 => return Ok((n, start.elapsed().as_secs_f64())),
            k => n += k,
        }
    }
}

fn main() -> eyre::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args.next().unwrap_or_else(|| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/real/prophesee-evt2-640x480.raw"
        )
        .into()
    });
    let passes: usize = match args.next() {
        Some(s) => s.parse().wrap_err_with(|| format!("PASSES: {s:?}"))?,
        None => 200,
    };
    let evt2 = std::fs::read(&path).wrap_err_with(|| format!("reading {path}"))?;
    let opts = ReadOptions::with_resolution(640, 480);
    let events = read_all(&mut RawReader::from_reader(&evt2[..], &path, &opts)?)?;
    let evt3 = |full_groups: bool| -> eyre::Result<Vec<u8>> {
        let mut w = Evt3Writer::new(Vec::new(), "memory", Resolution::new(640, 480))?;
        if full_groups {
            w = w.with_full_vector_groups();
        }
        w.write_batch(&events)?;
        Ok(w.finish()?.0)
    };
    let (shortest, groups) = (evt3(false)?, evt3(true)?);
    let files = [
        ("EVT 2.0", &evt2),
        ("EVT 3.0", &shortest),
        ("EVT 3.0, full vector groups", &groups),
    ];
    let mut times = [Vec::new(), Vec::new(), Vec::new()];
    for _ in 0..passes.max(1) {
        for ((name, bytes), t) in files.iter().zip(&mut times) {
            let (n, s) = pass(bytes, &opts)?;
            eyre::ensure!(
                n == events.len(),
                "{name}: {n} events, not {}",
                events.len()
            );
            t.push(s);
        }
    }
    println!("{} events, {} passes each", events.len(), passes.max(1));
    for ((name, bytes), t) in files.iter().zip(&mut times) {
        t.sort_by(f64::total_cmp);
        let rate = |s: f64| events.len() as f64 / s / 1e6;
        println!(
            "{name}: {} bytes, best {:.1} M events/s, median {:.1}",
            bytes.len(),
            rate(t[0]),
            rate(t[t.len() / 2])
        );
    }
    Ok(())
}
