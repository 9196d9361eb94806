//! How neuspike's tract operators split their output rows across tract's thread pool.

use std::sync::Arc;

use rayon::prelude::*;

/// The pool of tract's current executor (`None` when it runs on the calling thread).
pub fn tract_pool() -> Option<Arc<rayon::ThreadPool>> {
    match tract_linalg::multithread::current_tract_executor() {
        tract_linalg::multithread::Executor::MultiThread(pool) => Some(pool),
        _ => None,
    }
}

/// Rows per band for `rows` rows on `pool`: a few bands per thread, so a slow thread does not
/// hold the others up; all of them in one band on one thread. At least 1.
pub(crate) fn band_rows(rows: usize, pool: Option<&rayon::ThreadPool>) -> usize {
    let threads = pool.map_or(1, |p| p.current_num_threads());
    let bands = if threads > 1 {
        (4 * threads).min(rows)
    } else {
        1
    };
    rows.div_ceil(bands.max(1)).max(1)
}

/// `output`'s planes (`plane` values each; a last shorter one is kept as it is) cut in bands of
/// `rows` rows of `row` values: band `b` is `(b * rows, [its rows of every plane])`.
pub(crate) fn row_bands(
    output: &mut [f32],
    plane: usize,
    row: usize,
    rows: usize,
) -> Vec<(usize, Vec<&mut [f32]>)> {
    let per_band = (rows * row).max(1);
    let mut bands: Vec<(usize, Vec<&mut [f32]>)> = (0..plane.div_ceil(per_band))
        .map(|b| (b * rows, Vec::new()))
        .collect();
    for plane in output.chunks_mut(plane.max(1)) {
        for (band, part) in bands.iter_mut().zip(plane.chunks_mut(per_band)) {
            band.1.push(part);
        }
    }
    bands
}

/// The output tensors of the last frames, kept to be written again: an operator's output of the
/// same shape that nothing else holds any more (tract dropped it after the frame) is taken
/// again instead of a new zeroed one, whose zeroing and page faults took about 9% of
/// `neuspike-spike-8-lite`'s frame in 8 bits on one thread. The oldest go first past
/// [`KEPT_BYTES`].
static KEPT: std::sync::Mutex<Vec<Arc<tract_onnx::prelude::Tensor>>> =
    std::sync::Mutex::new(Vec::new());

/// The most bytes of output tensors [`KEPT`] holds: 256 MiB (every intermediate of the largest
/// shipped network at 256x400 takes about 100).
pub(crate) const KEPT_BYTES: usize = 256 << 20;

/// An `f32` tensor of `shape` with `write` run on its values, which are those of a kept tensor
/// (see [`KEPT`]) or zeros: `write` must set every value (each operator's tests fill its
/// output with NaN first and compare every value). It is made where tract keeps a
/// tensor's values: a `Vec` made into a tensor is copied into tract's own aligned buffer
/// (`Tensor::from_datum`), which with the page faults of the second buffer took about 1 ms a
/// frame of `neuspike-spike-8-lite` in 8 bits on one thread.
pub(crate) fn output_tensor(
    shape: &[usize],
    write: impl FnOnce(&mut [f32]) -> tract_onnx::prelude::TractResult<()>,
) -> tract_onnx::prelude::TractResult<tract_onnx::prelude::TValue> {
    use tract_onnx::tract_core::internal::*;
    let kept = {
        let mut kept = KEPT.lock().unwrap_or_else(|e| e.into_inner());
        let free = kept
            .iter_mut()
            .position(|t| t.shape() == shape && Arc::get_mut(t).is_some());
        free.map(|i| kept.remove(i))
    };
    let mut t = match kept {
        Some(t) => t,
        None => Arc::new(Tensor::zero::<f32>(shape)?),
    };
    let Some(tensor) = Arc::get_mut(&mut t) else {
        bail!("an output tensor held elsewhere");
    };
    write(tensor.try_as_plain_ram_mut()?.as_slice_mut::<f32>()?)?;
    let mut kept = KEPT.lock().unwrap_or_else(|e| e.into_inner());
    kept.push(t.clone());
    let bytes = |k: &[Arc<Tensor>]| k.iter().map(|t| t.len() * 4).sum::<usize>();
    while kept.len() > 1 && bytes(&kept) > KEPT_BYTES {
        kept.remove(0);
    }
    Ok(t.into_tvalue())
}

/// Runs `f` on every task: across `pool` when it has more than one thread, else in order here.
pub(crate) fn for_each<T: Send>(
    tasks: Vec<T>,
    pool: Option<&rayon::ThreadPool>,
    f: impl Fn(T) + Send + Sync,
) {
    match pool {
        Some(pool) if pool.current_num_threads() > 1 => {
            pool.install(|| tasks.into_par_iter().for_each(f))
        }
        _ => tasks.into_iter().for_each(f),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_cover_every_row_of_every_plane_once() {
        for (planes, h, w, rows) in [(3, 10, 4, 3), (1, 1, 1, 1), (2, 7, 5, 7), (2, 7, 5, 9)] {
            let mut out = vec![0.0f32; planes * h * w];
            let bands = row_bands(&mut out, h * w, w, rows);
            assert_eq!(bands.len(), h.div_ceil(rows));
            for (b, (y0, parts)) in bands.into_iter().enumerate() {
                assert_eq!(y0, b * rows);
                assert_eq!(parts.len(), planes);
                for part in parts {
                    assert_eq!(part.len(), rows.min(h - y0) * w);
                    part.iter_mut().for_each(|v| *v += 1.0);
                }
            }
            assert!(out.iter().all(|&v| v == 1.0), "{planes}x{h}x{w} by {rows}");
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        assert_eq!(band_rows(256, None), 256);
        assert_eq!(band_rows(256, Some(&pool)), 32);
        assert_eq!(band_rows(3, Some(&pool)), 1);
        assert_eq!(band_rows(0, Some(&pool)), 1);
    }
}
