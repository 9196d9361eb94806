//! Hostile bytes: a few forged bytes must not make a reader allocate what they claim, expand
//! without bound or read a file whole into one line. Each test reads a forged input under a
//! counting allocator and checks the error (file, field, value, the limit's name), the peak
//! memory the read took on this thread, and that it returned at once.
// Test code: a panic is how a failure is reported. The counting allocator implements the unsafe
// `GlobalAlloc` trait by handing every call to `System`.
#![allow(clippy::unwrap_used, unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Write;
use std::time::{Duration, Instant};

use neuspike_formats::aedat4::{
    Aedat4Frames, Aedat4Reader, Aedat4Writer, Compression, MAX_PACKET_BYTES,
};
use neuspike_formats::text::{MAX_LINE_BYTES, TextReader};
use neuspike_formats::{
    Event, EventBatch, EventReader, EventWriter, FormatError, ReadOptions, Resolution,
};

/// Counts the bytes live on each thread, and their peak (tests run on threads of their own).
struct Counting;

thread_local! {
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn count(delta: isize) {
    let _ = LIVE.try_with(|live| {
        let now = live.get() + delta;
        live.set(now);
        let _ = PEAK.try_with(|peak| peak.set(peak.get().max(now)));
    });
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            count(layout.size() as isize);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            count(layout.size() as isize);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) };
        count(-(layout.size() as isize));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count(new_size as isize - layout.size() as isize);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs `f`; returns what it gave, the most bytes it held at once on this thread, and how long
/// it took.
fn measured<T>(f: impl FnOnce() -> T) -> (T, usize, Duration) {
    let base = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(base));
    let start = Instant::now();
    let out = f();
    let took = start.elapsed();
    let peak = PEAK.with(Cell::get) - base;
    (out, peak.max(0) as usize, took)
}

const MIB: usize = 1 << 20;

/// Reads every event of `bytes` as AEDAT 4 under `opts`; the error that ends it.
fn aedat4_error(bytes: &[u8], opts: &ReadOptions) -> FormatError {
    let mut r = match Aedat4Reader::from_reader(bytes, "forged.aedat4", opts) {
        Ok(r) => r,
        Err(e) => return e,
    };
    let mut b = EventBatch::default();
    loop {
        match r.read_into(&mut b, 1000) {
            Ok(0) => panic!("no error after {} events", b.len()),
            Ok(_) => {}
            Err(e) => return e,
        }
    }
}

/// Our writer's file start (magic, `IOHeader` declaring stream 0 `EVTS` and 1 `FRME`), no packet.
fn header_only(c: Compression) -> Vec<u8> {
    let w = Aedat4Writer::new(Vec::new(), "w", Resolution::new(30, 20), c).unwrap();
    w.finish().unwrap().0
}

/// `header_only` followed by a packet header of `stream` claiming `size` bytes, and 16 bytes.
fn forged_packet(stream: i32, size: u32) -> Vec<u8> {
    let mut b = header_only(Compression::None);
    b.extend_from_slice(&stream.to_le_bytes());
    b.extend_from_slice(&size.to_le_bytes());
    b.extend_from_slice(&[0x5a; 16]);
    b
}

/// Asserts the read failed fast, within `max_peak` bytes.
fn assert_cheap(peak: usize, took: Duration, max_peak: usize) {
    assert!(peak < max_peak, "peak {peak} bytes (at most {max_peak})");
    assert!(took < Duration::from_millis(500), "took {took:?}");
}

#[test]
fn aedat4_io_header_claiming_16_mib_in_a_few_bytes_allocates_nothing_of_it() {
    let mut b = header_only(Compression::None)[..14].to_vec();
    b.extend_from_slice(&(16u32 << 20).to_le_bytes());
    b.extend_from_slice(b"IOHE and then nothing");
    let (e, peak, took) = measured(|| aedat4_error(&b, &ReadOptions::default()));
    assert_cheap(peak, took, MIB);
    let e = e.to_string();
    assert!(
        e.contains("forged.aedat4") && e.contains("truncated") && e.contains("16777216"),
        "{e}"
    );
    // One byte over the stated limit is refused by name before any read.
    let mut b = b[..14].to_vec();
    b.extend_from_slice(&((16u32 << 20) + 1).to_le_bytes());
    let e = aedat4_error(&b, &ReadOptions::default()).to_string();
    assert!(e.contains("aedat4::MAX_HEADER_BYTES"), "{e}");
}

#[test]
fn aedat4_io_header_longer_than_the_file_is_refused_from_the_file_length() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("short.aedat4");
    let mut b = header_only(Compression::None)[..14].to_vec();
    b.extend_from_slice(&1000u32.to_le_bytes());
    b.extend_from_slice(&[0; 10]);
    std::fs::write(&path, &b).unwrap();
    let e = Aedat4Reader::open(&path, &ReadOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("short.aedat4")
            && e.contains("IOHeader length 1000 bytes")
            && e.contains("10 bytes follow in the 28-byte file"),
        "{e}"
    );
}

#[test]
fn aedat4_packet_claiming_60_mib_in_16_bytes_allocates_nothing_of_it() {
    let size = 60u32 << 20;
    let b = forged_packet(0, size);
    let (e, peak, took) = measured(|| aedat4_error(&b, &ReadOptions::default()));
    assert_cheap(peak, took, 2 * MIB);
    let e = e.to_string();
    assert!(
        e.contains("forged.aedat4") && e.contains("truncated") && e.contains(&size.to_string()),
        "{e}"
    );
    // The same claim in a packet of another stream, skipped unread: nothing allocated either.
    let b = forged_packet(1, size);
    let (e, peak, took) = measured(|| aedat4_error(&b, &ReadOptions::default()));
    assert_cheap(peak, took, 2 * MIB);
    assert!(e.to_string().contains("truncated"), "{e}");
    let (e, peak, _) = measured(|| {
        Aedat4Frames::from_reader(&forged_packet(1, size)[..], "forged.aedat4")
            .unwrap()
            .find_map(Result::err)
            .unwrap()
    });
    assert!(peak < 2 * MIB, "frames: peak {peak}");
    assert!(e.to_string().contains("truncated"), "{e}");
}

#[test]
fn aedat4_packet_over_the_limit_is_refused_by_name_and_from_the_file_length() {
    let size = 300u32 << 20;
    let (e, peak, took) =
        measured(|| aedat4_error(&forged_packet(0, size), &ReadOptions::default()));
    assert_cheap(peak, took, 2 * MIB);
    let e = e.to_string();
    assert!(
        e.contains("forged.aedat4")
            && e.contains(&format!("size {size} bytes"))
            && e.contains(&format!("{MAX_PACKET_BYTES}-byte limit"))
            && e.contains("aedat4::MAX_PACKET_BYTES"),
        "{e}"
    );
    // Opened from a path, a claim beyond the file's end is named with what is left.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("claims.aedat4");
    let b = forged_packet(0, 1 << 20);
    std::fs::write(&path, &b).unwrap();
    let p = b.len() - 24;
    let (e, peak, took) = measured(|| {
        let mut r = Aedat4Reader::open(&path, &ReadOptions::default()).unwrap();
        r.read_into(&mut EventBatch::default(), 10).unwrap_err()
    });
    assert_cheap(peak, took, MIB);
    let e = e.to_string();
    assert!(
        e.contains("claims.aedat4")
            && e.contains(&format!("byte {p}"))
            && e.contains("size 1048576 bytes, but 16 bytes follow"),
        "{e}"
    );
}

/// Two LZ4 packets of 8,192 all-zero events: 131 KB each once decompressed, under 1 KB stored.
fn lz4_file_of_zeros() -> Vec<u8> {
    let r = Resolution::new(30, 20);
    let mut w = Aedat4Writer::new(Vec::new(), "w", r, Compression::Lz4).unwrap();
    for _ in 0..2 {
        for _ in 0..8192 {
            w.write_event(&Event {
                t_ns: 0,
                x: 0,
                y: 0,
                polarity: -1,
            })
            .unwrap();
        }
    }
    w.finish().unwrap().0
}

#[test]
fn aedat4_lz4_packet_expanding_past_the_limit_stops_at_the_limit() {
    let b = lz4_file_of_zeros();
    let opts = ReadOptions {
        max_packet_bytes: 64 * 1024,
        ..ReadOptions::default()
    };
    let (e, peak, took) = measured(|| aedat4_error(&b, &opts));
    // The decoder's own buffers (a 64 KiB block) and the payload, up to twice the limit.
    assert_cheap(peak, took, MIB);
    let e = e.to_string();
    assert!(
        e.contains("forged.aedat4")
            && e.contains("decompresses to more than 65536 bytes")
            && e.contains("aedat4::MAX_PACKET_BYTES"),
        "{e}"
    );
    // Under the default limit the same file reads.
    let mut r = Aedat4Reader::from_reader(&b[..], "ok", &ReadOptions::default()).unwrap();
    let mut out = EventBatch::default();
    while r.read_into(&mut out, 1 << 16).unwrap() > 0 {}
    assert_eq!(out.len(), 2 * 8192);
}

/// A Zstandard packet whose frame header asks for `window` bytes (single segment: the content
/// size, 8 bytes), and no block.
fn zstd_frame_asking(window: u64) -> Vec<u8> {
    let mut b = header_only(Compression::None);
    // The IOHeader's compression code (file byte 18 + 28): 3, Zstd.
    b[46] = 3;
    let mut frame = 0xFD2F_B528u32.to_le_bytes().to_vec();
    frame.push(0b1110_0000); // content size in 8 bytes, single segment
    frame.extend_from_slice(&window.to_le_bytes());
    b.extend_from_slice(&0i32.to_le_bytes());
    b.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    b.extend_from_slice(&frame);
    b
}

#[test]
fn aedat4_zstd_frame_asking_for_a_large_window_is_refused_before_decoding() {
    let window = 90u64 << 20;
    let b = zstd_frame_asking(window);
    let (e, peak, took) = measured(|| aedat4_error(&b, &ReadOptions::default()));
    assert_cheap(peak, took, MIB);
    let e = e.to_string();
    assert!(
        e.contains("forged.aedat4")
            && e.contains(&format!("{window}-byte window"))
            && e.contains("aedat4::MAX_PACKET_BYTES"),
        "{e}"
    );
    // Under the limit the decoder is asked, and fails on the missing block.
    let e = aedat4_error(&zstd_frame_asking(1000), &ReadOptions::default()).to_string();
    assert!(e.contains("does not decompress"), "{e}");
}

#[test]
fn text_without_a_line_feed_is_refused_at_the_line_limit() {
    let bytes = vec![b'7'; 4 * MIB];
    let (e, peak, took) = measured(|| {
        TextReader::from_reader(&bytes[..], "flat.txt", &ReadOptions::default())
            .err()
            .unwrap()
    });
    assert_cheap(peak, took, 256 * 1024);
    let e = e.to_string();
    assert!(
        e.contains("flat.txt")
            && e.contains("line 1")
            && e.contains(&format!("longer than {MAX_LINE_BYTES} bytes"))
            && e.contains("text::MAX_LINE_BYTES"),
        "{e}"
    );
    // A long line after good ones: the events before it are delivered, then its number.
    let mut text = b"2 2\n0.1 0 0 1\n0.2 1 1 0\n".to_vec();
    text.extend(std::iter::repeat_n(b' ', 10 * MAX_LINE_BYTES));
    text.extend_from_slice(b"0.3 1 1 1\n");
    let mut r = TextReader::from_reader(&text[..], "long.txt", &ReadOptions::default()).unwrap();
    let mut out = EventBatch::default();
    assert_eq!(r.read_into(&mut out, 100).unwrap(), 2);
    let e = r.read_into(&mut out, 100).unwrap_err().to_string();
    assert!(e.contains("long.txt: line 4: longer than 4096"), "{e}");
}

#[test]
fn text_line_limit_is_exact_and_adjustable() {
    // A comment of exactly the limit (line feed excluded) is read; one byte more is not.
    let line = |n: usize| {
        let mut l = vec![b'#'; n];
        l.extend_from_slice(b"\n0.1 0 0 1\n");
        l
    };
    let opts = ReadOptions::with_resolution(2, 2);
    let (at_limit, over) = (line(MAX_LINE_BYTES), line(MAX_LINE_BYTES + 1));
    let mut r = TextReader::from_reader(&at_limit[..], "t", &opts).unwrap();
    assert_eq!(r.read_into(&mut EventBatch::default(), 10).unwrap(), 1);
    let e = TextReader::from_reader(&over[..], "t", &opts)
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::Text { line: 1, .. }), "{e}");
    let wide = ReadOptions {
        max_line_bytes: 2 * MAX_LINE_BYTES,
        ..opts
    };
    let mut r = TextReader::from_reader(&over[..], "t", &wide).unwrap();
    assert_eq!(r.read_into(&mut EventBatch::default(), 10).unwrap(), 1);
}

#[test]
fn npy_header_claiming_a_mebibyte_in_a_few_bytes_allocates_nothing_of_it() {
    let mut b = b"\x93NUMPY\x02\x00".to_vec();
    b.extend_from_slice(&(1u32 << 20).to_le_bytes());
    b.extend_from_slice(b"{'descr'");
    let (e, peak, took) = measured(|| {
        neuspike_formats::npy::parse_header(&mut &b[..], std::path::Path::new("forged.npy"))
            .unwrap_err()
    });
    assert_cheap(peak, took, 64 * 1024);
    let e = e.to_string();
    assert!(
        e.contains("forged.npy") && e.contains("header length 1048576 bytes"),
        "{e}"
    );
}

/// The counting allocator counts: a sanity check of the tests above.
#[test]
fn the_counting_allocator_sees_an_allocation() {
    let (v, peak, _) = measured(|| {
        let mut v = Vec::<u8>::with_capacity(3 * MIB);
        v.write_all(&[1; 10]).unwrap();
        v
    });
    assert!(peak >= 3 * MIB, "{peak}");
    drop(v);
}
