//! Cheap statistics of one aligned window, for choosing a reconstruction method per window
//! (`--method auto`): how much light (firing rate), how much motion (event rate, and the change
//! of the spike counts between the window's halves), how wide the dynamic range (the spread of
//! block firing rates), and whether events exist at all. One pass over the packed planes.
//!
//! The view is cut into blocks of [`BLOCK`] x [`BLOCK`] pixels (partial blocks at the right and
//! bottom edges count as blocks of their own size). Definitions, with `a_b` and `b_b` the spikes
//! of block `b` in the first and second half of the planes (the middle plane of an odd window
//! goes to the second half) and `n_b` its pixels:
//! - `rate`: spikes per pixel per plane over the window, in [0, 1];
//! - `event_rate`: events per pixel per plane (0 without events or planes);
//! - `change`: `sum_b |a_b - b_b| / sum_b (a_b + b_b)`, in [0, 1]; 0 when no spike fired;
//! - `spread_decades`: `log10((q90 + 1) / (q10 + 1))` of the blocks' spike counts per pixel
//!   scaled to a full window (`(a_b + b_b) / n_b`), nearest-rank quantiles; the `+ 1` keeps the
//!   logarithm defined for dark blocks (a block that never fired reads as one spike);
//! - `edge`: how much texture the view holds, the quantity a moving scene's events are
//!   proportional to. The view is cut again into whole cells of [`CELL`] x [`CELL`] pixels
//!   (pixels past the last whole cell at the right and bottom are left out); with `s_c` the
//!   spikes of cell `c` over the window, `edge` is the mean over horizontally and vertically
//!   adjacent cells `c, d` of `|s_c - s_d| / (s_c + s_d)` (a pair that never fired counts 0), in
//!   [0, 1]; 0 without a pair. Summing a cell's pixels keeps the integrate-and-fire counts'
//!   quantisation (at most one spike per pixel) small against the cell's count, so
//!   `event_rate / edge` reads the speed of the scene whatever its texture.

use ndarray::Array2;
use neuspike_schemas::{AlignedWindow, SpikeChunk, bytes_per_plane};

use crate::tfp_packed_into;

/// Block side, pixels.
pub const BLOCK: usize = 16;

/// Side of the cells `edge` compares, pixels.
pub const CELL: usize = 4;

/// The statistics of one window (see the module's definitions).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WindowStats {
    /// Spikes per pixel per plane.
    pub rate: f64,
    /// Events per pixel per plane.
    pub event_rate: f64,
    /// Change of the block spike counts between the window's halves.
    pub change: f64,
    /// Decades between the 90th and 10th percentile block firing counts.
    pub spread_decades: f64,
    /// Whether the window holds any event.
    pub events: bool,
    /// Mean relative difference of the spike counts of adjacent cells: texture.
    pub edge: f64,
}

/// The spike counts a window's statistics are computed from.
struct Counts {
    /// Per block, row-major: spikes in the first half, in the second half, pixels.
    blocks: Vec<(u64, u64, u64)>,
    /// Per whole cell, row-major: spikes over the window.
    cells: Vec<u64>,
    /// Whole cells per row.
    cells_x: usize,
}

/// The counts of all of `w`'s planes.
fn counts(w: &AlignedWindow) -> Counts {
    counts_of(&w.spikes, 0..w.spikes.n_planes)
}

/// The counts of the planes `planes` of `s`. Each half's per-pixel counts come from the
/// bit-sliced TFP kernel ([`tfp_packed_into`]: the rate over `m` planes times `m`, exact in `f32`
/// for `m <= MAX_PLANES`), then summed per block and per cell.
fn counts_of(s: &SpikeChunk, planes: std::ops::Range<usize>) -> Counts {
    let (width, height) = (s.width, s.height);
    let (p0, n) = (planes.start, planes.len());
    let bx = width.div_ceil(BLOCK);
    let by = height.div_ceil(BLOCK);
    let mut blocks: Vec<(u64, u64, u64)> = (0..by * bx)
        .map(|b| {
            let (r, c) = (b / bx, b % bx);
            let h = BLOCK.min(height - r * BLOCK);
            let wd = BLOCK.min(width - c * BLOCK);
            (0, 0, (h * wd) as u64)
        })
        .collect();
    let (cx, cy) = (width / CELL, height / CELL);
    let mut cells = vec![0u64; cx * cy];
    let half = p0 + n / 2;
    let mut rate = Array2::<f32>::zeros((height, width));
    for (range, second) in [(p0..half, false), (half..p0 + n, true)] {
        let m = range.len();
        if m == 0 || width == 0 || height == 0 {
            continue;
        }
        // The window's planes are whole (the message was checked): the kernel cannot refuse.
        if tfp_packed_into(&s.bits, range, rate.view_mut()).is_err() {
            continue;
        }
        // Each pixel's rate is k / m: a sum of rates times m is a spike count.
        let spikes =
            |chunk: &[f32]| (f64::from(chunk.iter().sum::<f32>()) * m as f64).round() as u64;
        for (y, row) in rate.rows().into_iter().enumerate() {
            let Some(row) = row.to_slice() else { continue };
            let base = (y / BLOCK) * bx;
            for (c, chunk) in row.chunks(BLOCK).enumerate() {
                let k = spikes(chunk);
                let b = &mut blocks[base + c];
                if second {
                    b.1 += k;
                } else {
                    b.0 += k;
                }
            }
            if y < cy * CELL {
                let line = &mut cells[(y / CELL) * cx..(y / CELL + 1) * cx];
                for (cell, chunk) in line.iter_mut().zip(row.chunks_exact(CELL)) {
                    *cell += spikes(chunk);
                }
            }
        }
    }
    Counts {
        blocks,
        cells,
        cells_x: cx,
    }
}

/// The window's statistics (about 0.45 ms for 33 planes at 400x250 on one core: see
/// `benches/bench_spike.rs`).
pub fn window_stats(w: &AlignedWindow) -> WindowStats {
    let s = &w.spikes;
    let pixels = (s.width * s.height) as f64;
    let planes = s.n_planes as f64;
    stats_from_counts(&counts(w), pixels, planes, w.events.t_ns.len())
}

/// The mean relative difference of adjacent cells (the module's `edge`).
fn edge(cells: &[u64], cells_x: usize) -> f64 {
    let rel = |a: u64, b: u64| {
        let sum = a + b;
        if sum == 0 {
            0.0
        } else {
            a.abs_diff(b) as f64 / sum as f64
        }
    };
    let (mut total, mut pairs) = (0.0, 0usize);
    if cells_x == 0 {
        return 0.0;
    }
    for (i, &a) in cells.iter().enumerate() {
        if (i + 1) % cells_x != 0 {
            total += rel(a, cells[i + 1]);
            pairs += 1;
        }
        if let Some(&b) = cells.get(i + cells_x) {
            total += rel(a, b);
            pairs += 1;
        }
    }
    if pairs == 0 {
        0.0
    } else {
        total / pairs as f64
    }
}

fn stats_from_counts(counts: &Counts, pixels: f64, planes: f64, events: usize) -> WindowStats {
    let blocks = &counts.blocks;
    let total: u64 = blocks.iter().map(|b| b.0 + b.1).sum();
    let diff: u64 = blocks.iter().map(|b| b.0.abs_diff(b.1)).sum();
    let denom = pixels * planes;
    let rate = if denom > 0.0 {
        total as f64 / denom
    } else {
        0.0
    };
    let event_rate = if denom > 0.0 {
        events as f64 / denom
    } else {
        0.0
    };
    let change = if total > 0 {
        diff as f64 / total as f64
    } else {
        0.0
    };
    let mut per_pixel: Vec<f64> = blocks
        .iter()
        .filter(|b| b.2 > 0)
        .map(|b| (b.0 + b.1) as f64 / b.2 as f64)
        .collect();
    per_pixel.sort_by(f64::total_cmp);
    let q = |p: f64| -> f64 {
        if per_pixel.is_empty() {
            return 0.0;
        }
        let rank = ((p * per_pixel.len() as f64).ceil() as usize).clamp(1, per_pixel.len());
        per_pixel[rank - 1]
    };
    WindowStats {
        rate,
        event_rate,
        change,
        spread_decades: ((q(0.9) + 1.0) / (q(0.1) + 1.0)).log10(),
        events: events > 0,
        edge: edge(&counts.cells, counts.cells_x),
    }
}

/// The statistics of the `n` central planes of `w`, as [`window_stats`] gives them for
/// `w.crop(n)`, without copying the crop (its events are only counted); `None` when `w` does not
/// hold `n` planes around its reference plane (or `n` is 0).
pub fn central_window_stats(w: &AlignedWindow, n: usize) -> Option<WindowStats> {
    let span = w.central(n)?;
    let s = &w.spikes;
    Some(stats_from_counts(
        &counts_of(s, span.first..span.first + n),
        (s.width * s.height) as f64,
        n as f64,
        span.events.len(),
    ))
}

/// The statistics a method is chosen from: those of the `n` central planes of `w`
/// ([`central_window_stats`]), with the event rate the larger of theirs and that over the
/// `span` central planes (when `w` holds them): a method that reads `span` planes needs the
/// scene still over all of them, so a window still now but moving a few planes away (a scene
/// that starts to move) reads as moving. In a steady scene the two rates agree. `None` as for
/// [`central_window_stats`].
pub fn choice_stats(w: &AlignedWindow, n: usize, span: usize) -> Option<WindowStats> {
    let mut s = central_window_stats(w, n)?;
    if let Some(wide) = w.central(span).filter(|_| span > n) {
        let denom = (w.spikes.width * w.spikes.height * span) as f64;
        if denom > 0.0 {
            let rate = wide.events.len() as f64 / denom;
            if rate > s.event_rate {
                s.event_rate = rate;
                s.events = true;
            }
        }
    }
    Some(s)
}

/// The scalar reference of [`window_stats`]: every pixel unpacked and counted one by one.
pub fn window_stats_reference(w: &AlignedWindow) -> WindowStats {
    let s = &w.spikes;
    let (width, height, n) = (s.width, s.height, s.n_planes);
    let bx = width.div_ceil(BLOCK);
    let by = height.div_ceil(BLOCK);
    let mut blocks = vec![(0u64, 0u64, 0u64); bx * by];
    for y in 0..height {
        for x in 0..width {
            blocks[(y / BLOCK) * bx + x / BLOCK].2 += 1;
        }
    }
    let (cx, cy) = (width / CELL, height / CELL);
    let mut cells = vec![0u64; cx * cy];
    let per = bytes_per_plane(width, height);
    for p in 0..n {
        for y in 0..height {
            for x in 0..width {
                let k = y * width + x;
                if s.bits[p * per + (k >> 3)] >> (k & 7) & 1 == 1 {
                    let b = &mut blocks[(y / BLOCK) * bx + x / BLOCK];
                    if p < n / 2 {
                        b.0 += 1;
                    } else {
                        b.1 += 1;
                    }
                    if x < cx * CELL && y < cy * CELL {
                        cells[(y / CELL) * cx + x / CELL] += 1;
                    }
                }
            }
        }
    }
    stats_from_counts(
        &Counts {
            blocks,
            cells,
            cells_x: cx,
        },
        (width * height) as f64,
        n as f64,
        w.events.t_ns.len(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::{EventBatch, SpikeChunk};
    use proptest::prelude::*;

    fn window(
        width: usize,
        height: usize,
        n: usize,
        bits: Vec<u8>,
        events: usize,
    ) -> AlignedWindow {
        let mut ev = EventBatch::empty(width, height, 0, 1_000, 0);
        for i in 0..events {
            ev.t_ns.push(i as i64);
            ev.x.push(0);
            ev.y.push(0);
            ev.polarity.push(1);
        }
        AlignedWindow {
            t_ref_ns: 0,
            ref_plane: (n / 2) as u64,
            spikes: SpikeChunk {
                width,
                height,
                first_plane: 0,
                n_planes: n,
                t_first_ns: 0,
                plane_period_ns: 50_000,
                seq: 0,
                bits,
                lum_per_rate: None,
            },
            events: ev,
        }
    }

    proptest! {
        #[test]
        fn the_fast_path_equals_the_reference(
            width in 1usize..70, height in 1usize..40, n in 1usize..6, seed in any::<u64>(), events in 0usize..5,
        ) {
            let per = bytes_per_plane(width, height);
            let mut x = seed | 1;
            let bits: Vec<u8> = (0..n * per).map(|_| { x ^= x << 13; x ^= x >> 7; x ^= x << 17; x as u8 }).collect();
            let w = window(width, height, n, bits, events);
            prop_assert_eq!(window_stats(&w), window_stats_reference(&w));
        }

        #[test]
        fn central_statistics_are_those_of_the_crop(
            width in 1usize..70, height in 1usize..40, n in 1usize..9, m in 0usize..10,
            seed in any::<u64>(), events in 0usize..12,
        ) {
            let per = bytes_per_plane(width, height);
            let mut x = seed | 1;
            let bits: Vec<u8> = (0..n * per).map(|_| { x ^= x << 13; x ^= x >> 7; x ^= x << 17; x as u8 }).collect();
            let mut w = window(width, height, n, bits, 0);
            // Events every 30 us from one plane before the first: some in the crop, some not.
            for i in 0..events {
                w.events.t_ns.push(i as i64 * 30_000 - 50_000);
                w.events.x.push(0);
                w.events.y.push(0);
                w.events.polarity.push(1);
            }
            w.events.t_start_ns = -50_000;
            prop_assert_eq!(central_window_stats(&w, m), w.crop(m).map(|c| window_stats(&c)));
        }
    }

    #[test]
    fn a_long_method_sees_the_motion_anywhere_in_its_span() {
        let (w, h, n) = (16, 8, 40);
        let per = bytes_per_plane(w, h);
        let mut win = window(w, h, n, vec![0x55; n * per], 0);
        // Planes are 50 us apart and the reference plane is plane 20: the 4 central planes hold
        // no event, the 32 central planes hold ten, 50 us apart from plane 6 on.
        for i in 0..10 {
            win.events.t_ns.push(300_000 + i * 50_000);
            win.events.x.push(0);
            win.events.y.push(0);
            win.events.polarity.push(1);
        }
        win.events.t_end_ns = 2_000_000;
        let still = central_window_stats(&win, 4).expect("fits");
        assert_eq!((still.event_rate, still.events), (0.0, false));
        let s = choice_stats(&win, 4, 32).expect("fits");
        assert!(
            s.events && (s.event_rate - 10.0 / (16.0 * 8.0 * 32.0)).abs() < 1e-15,
            "{s:?}"
        );
        // Everything else is the central planes'; a span the window does not hold, or no wider
        // than the statistics', changes nothing.
        assert_eq!(
            (s.rate, s.change, s.edge),
            (still.rate, still.change, still.edge)
        );
        assert_eq!(choice_stats(&win, 4, 64), Some(still));
        assert_eq!(choice_stats(&win, 4, 4), Some(still));
    }

    #[test]
    fn edges_are_defined_and_the_figures_mean_what_they_say() {
        // No spikes, no events: all zero, spread 0 (log10 of 1).
        let (w, h, n) = (32, 16, 4);
        let per = bytes_per_plane(w, h);
        let s = window_stats(&window(w, h, n, vec![0; n * per], 0));
        assert_eq!(s, WindowStats::default());
        // Every pixel every plane: rate 1, no change, no spread.
        let s = window_stats(&window(w, h, n, vec![0xff; n * per], 3));
        assert_eq!((s.rate, s.change, s.spread_decades), (1.0, 0.0, 0.0));
        assert!(s.events && s.event_rate == 3.0 / (32.0 * 16.0 * 4.0));
        // Spikes only in the second half: change 1.
        let mut bits = vec![0u8; n * per];
        bits[2 * per..].fill(0xff);
        let s = window_stats(&window(w, h, n, bits, 0));
        assert_eq!((s.rate, s.change), (0.5, 1.0));
        // Left block always fires, right block never: a decade-scale spread.
        let mut bits = vec![0u8; n * per];
        for p in 0..n {
            for y in 0..h {
                bits[p * per + y * 4] = 0xff;
                bits[p * per + y * 4 + 1] = 0xff;
            }
        }
        let s = window_stats(&window(w, h, n, bits, 0));
        assert!((s.spread_decades - (5.0f64).log10()).abs() < 1e-12, "{s:?}");
        // Of the 8 x 4 cells' 28 horizontal and 24 vertical pairs, the 4 across the step differ
        // wholly.
        assert!((s.edge - 4.0 / 52.0).abs() < 1e-12, "{s:?}");
        // Cells of a checkerboard differ wholly from every neighbour; a uniform view holds none.
        let mut bits = vec![0u8; n * per];
        for p in 0..n {
            for y in 0..h {
                for x in (0..w).filter(|x| (x / CELL + y / CELL).is_multiple_of(2)) {
                    let k = y * w + x;
                    bits[p * per + k / 8] |= 1 << (k % 8);
                }
            }
        }
        assert_eq!(window_stats(&window(w, h, n, bits, 0)).edge, 1.0);
        assert_eq!(
            window_stats(&window(w, h, n, vec![0xff; n * per], 0)).edge,
            0.0
        );
        // Views narrower or lower than a cell hold no pair.
        let s = window_stats(&window(3, 40, n, vec![0xff; n * bytes_per_plane(3, 40)], 0));
        assert_eq!(s.edge, 0.0);
        // Empty window: no division by zero.
        let s = window_stats(&window(0, 0, 0, vec![], 0));
        assert_eq!(s, WindowStats::default());
    }
}
