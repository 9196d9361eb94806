//! The camera model against a real recording: inter-spike-interval (ISI) histograms at matched
//! firing rates.
//!
//! A real recording's still pixels (those whose rate is the same in each quarter of the
//! recording) are sorted into bands of firing rate: dark, mid and bright. For each such pixel the
//! model simulates a pixel whose light gives the same mean rate, over as many planes, and the ISIs
//! of the real and the simulated pixels of each band are compared as histograms, by the
//! Wasserstein-1 distance (in ticks: the area between the two cumulative distributions) and the
//! Kullback-Leibler divergence of the real from the simulated (in nats, the simulated histogram
//! smoothed by [`KL_FLOOR`] so that it is finite).
//!
//! Matching the rates pixel by pixel makes the fixed-pattern terms (gain, threshold offset, dark
//! current: each only moves a pixel's rate) invisible to this comparison; it measures what shapes
//! the intervals at a given rate: the per-interval noise (shot noise and jitter) and the reset.
//! [`fit`] finds the per-interval sigma that minimises the mean distance over the bands.

use crate::noise::{MAX_FIRE_SIGMA, Noise};
use crate::{FireNoise, KeyLight, PixelState, Reset, integrate_ticks, integrate_ticks_noisy};
use neuspike_schemas::{SpikeChunk, fired_pixels};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A band of firing rates, spikes per plane, `[lo, hi)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Band {
    /// Its name in reports.
    pub name: &'static str,
    /// Lowest rate.
    pub lo: f64,
    /// Rate above the band.
    pub hi: f64,
}

/// The bands compared: dark (ISI 7-25 ticks), mid (3-7) and bright (1.3-3). Saturated pixels
/// (ISI 1 every tick) say nothing about noise and are left out.
pub const BANDS: [Band; 3] = [
    Band {
        name: "dark",
        lo: 0.04,
        hi: 0.15,
    },
    Band {
        name: "mid",
        lo: 0.15,
        hi: 0.35,
    },
    Band {
        name: "bright",
        lo: 0.35,
        hi: 0.75,
    },
];

/// ISIs longer than this are counted in the last bin.
pub const MAX_ISI: usize = 64;

/// The probability every bin of a simulated histogram is given at least, for the KL divergence.
pub const KL_FLOOR: f64 = 1e-4;

/// A still pixel's rate may differ between quarters of the recording by at most this, spikes per
/// plane.
pub const STILL_TOLERANCE: f64 = 0.06;

/// The histogram of ISIs: `counts[d]` intervals of `d` ticks (`d = 1..=MAX_ISI`, the last bin
/// holding the longer ones; bin 0 is unused).
#[derive(Clone, Debug, PartialEq)]
pub struct Histogram {
    /// Counts per interval length.
    pub counts: Vec<u64>,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            counts: vec![0; MAX_ISI + 1],
        }
    }
}

impl Histogram {
    /// Counts the intervals between consecutive spikes at `times` (ascending).
    pub fn add_train(&mut self, times: &[u32]) {
        for w in times.windows(2) {
            let d = (w[1] - w[0]) as usize;
            self.counts[d.clamp(1, MAX_ISI)] += 1;
        }
    }

    /// Intervals counted.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Mean interval, ticks (0 for an empty histogram).
    pub fn mean(&self) -> f64 {
        let t = self.total();
        if t == 0 {
            return 0.0;
        }
        let s: f64 = self
            .counts
            .iter()
            .enumerate()
            .map(|(d, &c)| d as f64 * c as f64)
            .sum();
        s / t as f64
    }

    /// The histogram as probabilities (all 0 when empty).
    pub fn probabilities(&self) -> Vec<f64> {
        let t = self.total().max(1) as f64;
        self.counts.iter().map(|&c| c as f64 / t).collect()
    }
}

/// Wasserstein-1 distance between two ISI histograms, ticks: the sum over lengths of the
/// difference of the cumulative distributions. `None` when either is empty.
pub fn wasserstein(a: &Histogram, b: &Histogram) -> Option<f64> {
    if a.total() == 0 || b.total() == 0 {
        return None;
    }
    let (pa, pb) = (a.probabilities(), b.probabilities());
    let (mut ca, mut cb, mut w) = (0.0, 0.0, 0.0);
    for (x, y) in pa.iter().zip(&pb) {
        ca += x;
        cb += y;
        w += (ca - cb).abs();
    }
    Some(w)
}

/// KL divergence of `real` from `model`, nats: `sum p ln(p / q)` over the lengths `real` has,
/// `q` floored at [`KL_FLOOR`] and renormalised. `None` when either is empty.
pub fn kl_divergence(real: &Histogram, model: &Histogram) -> Option<f64> {
    if real.total() == 0 || model.total() == 0 {
        return None;
    }
    let p = real.probabilities();
    let q: Vec<f64> = model
        .probabilities()
        .iter()
        .map(|v| v.max(KL_FLOOR))
        .collect();
    let qs: f64 = q.iter().sum();
    Some(
        p.iter()
            .zip(&q)
            .filter(|(p, _)| **p > 0.0)
            .map(|(p, q)| p * (p / (q / qs)).ln())
            .sum(),
    )
}

/// Every pixel's spike times (plane indices) in a chunk.
pub fn spike_trains(chunk: &SpikeChunk) -> Vec<Vec<u32>> {
    let n = chunk.width * chunk.height;
    let per = n.div_ceil(8);
    let mut trains = vec![Vec::new(); n];
    for (k, plane) in chunk.bits.chunks_exact(per.max(1)).enumerate() {
        for i in fired_pixels(plane, n) {
            trains[i].push(k as u32);
        }
    }
    trains
}

/// A recording's still pixels, the ones compared: index, rate (spikes per plane) and band.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// Planes in the recording.
    pub planes: usize,
    /// Still pixels in a band: (pixel, rate, band index).
    pub pixels: Vec<(usize, f64, usize)>,
    /// The real ISI histogram of each band.
    pub real: Vec<Histogram>,
}

impl Reference {
    /// The still pixels of a recording and their ISI histograms per band.
    ///
    /// # Errors
    /// Fewer than 40 planes (a quarter must hold an interval of the dark band).
    pub fn from_recording(chunk: &SpikeChunk) -> Result<Reference, String> {
        let planes = chunk.n_planes;
        if planes < 40 {
            return Err(format!(
                "{planes} planes: comparing intervals needs at least 40"
            ));
        }
        let trains = spike_trains(chunk);
        let quarter = planes / 4;
        let mut pixels = Vec::new();
        let mut real = vec![Histogram::default(); BANDS.len()];
        for (i, t) in trains.iter().enumerate() {
            let rate = t.len() as f64 / planes as f64;
            let Some(band) = BANDS.iter().position(|b| rate >= b.lo && rate < b.hi) else {
                continue;
            };
            let q = |j: usize| {
                let (lo, hi) = ((j * quarter) as u32, ((j + 1) * quarter) as u32);
                t.iter().filter(|&&k| k >= lo && k < hi).count() as f64 / quarter as f64
            };
            let still = (0..4).all(|j| (q(j) - rate).abs() <= STILL_TOLERANCE);
            if still {
                pixels.push((i, rate, band));
                real[band].add_train(t);
            }
        }
        Ok(Reference {
            planes,
            pixels,
            real,
        })
    }

    /// The model's ISI histogram of each band: a pixel per still pixel, lit to give its rate,
    /// with the paper's random initial charge and ISI cap and `noise`'s per-interval terms, over
    /// as many planes as the recording.
    pub fn simulate(&self, noise: &Noise, seed: u64) -> Vec<Histogram> {
        let n = self.pixels.len();
        let phi = 1.0f32;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Light for rate r: an interval collects phi plus the light lost to the reset delay,
        // so r = l / (phi + d l) and l = r phi / (1 - r d) (r d < 0.75 here: d < 1, r < 0.75).
        let d = noise.reset_delay_ticks;
        let base: Vec<f32> = self
            .pixels
            .iter()
            .map(|&(_, r, _)| (r * f64::from(phi) / (1.0 - r * d)) as f32)
            .collect();
        let mut acc: Vec<f32> = (0..n).map(|_| rng.random::<f32>() * phi).collect();
        let normal = rand_distr::Normal::new(180.0f64, 50.0).expect("the paper's cap");
        let cap: Vec<u32> = (0..n)
            .map(|_| {
                rand_distr::Distribution::sample(&normal, &mut rng)
                    .round()
                    .clamp(1.0, f64::from(u32::MAX)) as u32
            })
            .collect();
        let mut since = vec![0u32; n];
        let mut thr = vec![phi; n];
        let mut state: Vec<u32> = (0..n).map(|_| rng.random::<u32>() | 1).collect();
        let per = n.div_ceil(8);
        let mut bits = vec![0u8; per * self.planes];
        // Still light: the same at both ends of the interval.
        let light = KeyLight {
            keys: &[&base, &base],
            step: 1,
        };
        let px = PixelState {
            acc: &mut acc,
            since: &mut since,
            cap: &cap,
        };
        if noise.per_fire() {
            let fire = FireNoise {
                sigma: noise.fire_sigma() as f32,
                reset_delay: d as f32,
                thr: &mut thr,
                rng: &mut state,
            };
            integrate_ticks_noisy(light, 0, phi, Reset::Subtract, px, fire, &mut bits);
        } else {
            integrate_ticks(light, 0, phi, Reset::Subtract, px, &mut bits);
        }
        let chunk = SpikeChunk {
            width: n,
            height: 1,
            first_plane: 0,
            n_planes: self.planes,
            t_first_ns: 0,
            plane_period_ns: 1,
            seq: 0,
            bits,
            lum_per_rate: None,
        };
        let mut out = vec![Histogram::default(); BANDS.len()];
        for (t, &(_, _, band)) in spike_trains(&chunk).iter().zip(&self.pixels) {
            out[band].add_train(t);
        }
        out
    }

    /// The distances of a model from the recording, per band and their mean.
    pub fn score(&self, noise: &Noise, seed: u64) -> Score {
        let sim = self.simulate(noise, seed);
        let per_band: Vec<(Option<f64>, Option<f64>)> = self
            .real
            .iter()
            .zip(&sim)
            .map(|(r, s)| (wasserstein(r, s), kl_divergence(r, s)))
            .collect();
        let mean = |v: Vec<f64>| {
            if v.is_empty() {
                f64::NAN
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            }
        };
        let mean_wasserstein = mean(per_band.iter().filter_map(|b| b.0).collect());
        let mean_kl = mean(per_band.iter().filter_map(|b| b.1).collect());
        Score {
            wasserstein: per_band.iter().map(|b| b.0).collect(),
            kl: per_band.iter().map(|b| b.1).collect(),
            mean_wasserstein,
            mean_kl,
            simulated: sim,
        }
    }
}

/// A model's distances from a recording.
#[derive(Clone, Debug)]
pub struct Score {
    /// Wasserstein-1 per band, ticks (`None`: the band is empty).
    pub wasserstein: Vec<Option<f64>>,
    /// KL divergence per band, nats.
    pub kl: Vec<Option<f64>>,
    /// Mean Wasserstein-1 over the bands that have pixels (NaN when none has).
    pub mean_wasserstein: f64,
    /// Mean KL divergence over the bands that have pixels.
    pub mean_kl: f64,
    /// The simulated histograms.
    pub simulated: Vec<Histogram>,
}

/// The per-interval sigma that minimises the mean Wasserstein distance, with `base`'s other
/// terms: a grid of steps of 0.005 up to [`MAX_FIRE_SIGMA`], then the shot-noise part of `base`
/// kept and the rest given to the jitter. Returns the fitted noise and its score.
pub fn fit(reference: &Reference, base: &Noise, seed: u64) -> (Noise, Score) {
    let shot = if base.electrons_per_phi > 0.0 {
        1.0 / base.electrons_per_phi
    } else {
        0.0
    };
    let with_sigma = |sigma: f64| Noise {
        threshold_jitter: (sigma * sigma - shot).max(0.0).sqrt(),
        ..*base
    };
    let mut best: Option<(Noise, Score)> = None;
    let steps = (MAX_FIRE_SIGMA / 0.005).round() as usize;
    for k in 0..=steps {
        let noise = with_sigma(k as f64 * 0.005);
        let score = reference.score(&noise, seed);
        let better = best
            .as_ref()
            .is_none_or(|(_, b)| score.mean_wasserstein < b.mean_wasserstein);
        if better {
            best = Some((noise, score));
        }
    }
    best.expect("at least one step")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist(pairs: &[(usize, u64)]) -> Histogram {
        let mut h = Histogram::default();
        for &(d, c) in pairs {
            h.counts[d] = c;
        }
        h
    }

    #[test]
    fn distances_between_histograms() {
        let a = hist(&[(2, 10)]);
        let b = hist(&[(3, 10)]);
        // All mass moved by one tick.
        assert!((wasserstein(&a, &b).unwrap() - 1.0).abs() < 1e-12);
        assert!(wasserstein(&a, &a).unwrap().abs() < 1e-12);
        assert!(kl_divergence(&a, &a).unwrap().abs() < 0.01);
        assert!(kl_divergence(&a, &b).unwrap() > 5.0);
        assert_eq!(wasserstein(&a, &Histogram::default()), None);
        let mut long = Histogram::default();
        long.add_train(&[0, 1000]);
        assert_eq!(long.counts[MAX_ISI], 1);
        assert!((hist(&[(2, 1), (4, 1)]).mean() - 3.0).abs() < 1e-12);
    }

    /// A recording made by the model itself is matched best near its own sigma.
    #[test]
    fn the_fit_recovers_the_sigma_of_a_simulated_recording() {
        let truth = Noise {
            threshold_jitter: 0.08,
            ..Noise::OFF
        };
        // 3,000 pixels of rates across the bands, 400 planes, simulated by the model.
        let pixels: Vec<(usize, f64, usize)> = (0..3000)
            .map(|i| {
                let r = 0.05 + 0.65 * (i as f64 / 3000.0);
                let band = BANDS.iter().position(|b| r >= b.lo && r < b.hi).unwrap();
                (i, r, band)
            })
            .collect();
        let mut reference = Reference {
            planes: 400,
            pixels,
            real: Vec::new(),
        };
        reference.real = reference.simulate(&truth, 1);
        let (fitted, score) = fit(&reference, &Noise::OFF, 2);
        assert!(
            (fitted.fire_sigma() - 0.08).abs() <= 0.015,
            "fitted {}",
            fitted.fire_sigma()
        );
        let paper = reference.score(&Noise::OFF, 2);
        assert!(score.mean_wasserstein < paper.mean_wasserstein / 2.0);
    }

    #[test]
    fn still_pixels_are_found_in_their_bands() {
        // 16 pixels, 80 planes: pixel i fires every (i % 8 + 2) planes; pixels 8.. stop after
        // half the recording (not still).
        let (w, planes) = (16usize, 80usize);
        let mut bits = vec![0u8; 2 * planes];
        for k in 0..planes {
            for i in 0..w {
                let period = i % 8 + 2;
                if k % period == 0 && (i < 8 || k < planes / 2) {
                    bits[k * 2 + i / 8] |= 1 << (i % 8);
                }
            }
        }
        let chunk = SpikeChunk {
            width: w,
            height: 1,
            first_plane: 0,
            n_planes: planes,
            t_first_ns: 0,
            plane_period_ns: 50_000,
            seq: 0,
            bits,
            lum_per_rate: None,
        };
        let r = Reference::from_recording(&chunk).unwrap();
        let found: Vec<usize> = r.pixels.iter().map(|p| p.0).collect();
        // Periods 2 (rate 0.5, bright) .. 9 (0.11, dark); the moving ones are left out.
        assert_eq!(found, (0..8).collect::<Vec<_>>());
        assert_eq!(r.pixels[0].2, 2);
        assert_eq!(r.pixels[7].2, 0);
        assert_eq!(r.real[2].counts[2], 39);
        let short = SpikeChunk {
            n_planes: 10,
            bits: vec![0; 20],
            ..chunk
        };
        assert!(
            Reference::from_recording(&short)
                .unwrap_err()
                .contains("10 planes")
        );
    }
}
