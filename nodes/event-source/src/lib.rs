//! The DVS event-camera model (DAVIS346-like) on the same scenes as the spike camera.
//!
//! Each pixel compares its log intensity `L = ln(max(I, log_floor))` against a reference level.
//! Whenever `L` rises by the pixel's ON threshold above the reference it emits an ON event and
//! moves the reference up by that threshold; likewise for OFF. Thresholds are
//! `theta * (1 + sigma * n)` with `n ~ N(0, 1)` drawn once per pixel (mismatch), clamped to at least
//! `MIN_THRESHOLD`.
//!
//! **Sampling and why no crossing is lost.** The scene is sampled every `step_ns`, and `L` is taken
//! as linear between two samples. Every crossing of the piecewise-linear `L` is emitted, however
//! many fall in one step (several events per step), each at its interpolated time. What
//! linear interpolation could miss is a change that goes and comes back between two samples; the
//! step is therefore chosen so that no point of the image moves more than `max_shift_px` (default
//! 0.25) pixels between samples, and at most `max_step_ns`. Textures are bilinear, so over a
//! quarter-pixel shift a pixel's intensity is monotone to within the texture's curvature.
//!
//! **Refractory period.** After an event a pixel emits nothing for `refractory_ns`; crossings that
//! fall inside it leave the reference where it was, so they are emitted (late, at the end of the
//! refractory period at the earliest) once the pixel is free, as a real pixel held in reset would.
//!
//! Deterministic for a seed.
#![deny(missing_docs)]

use ndarray::Array2;
use neuspike_scene::Scene;
use neuspike_schemas::{Event, EventBatch};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Smallest contrast threshold a mismatch draw may produce.
pub const MIN_THRESHOLD: f64 = 0.01;

/// DVS settings. Every field is a node argument in the graph YAML.
#[derive(Clone, Debug, clap::Args)]
pub struct DvsConfig {
    /// Sensor width in pixels.
    #[arg(long, default_value_t = 346)]
    pub width: usize,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 260)]
    pub height: usize,
    /// ON contrast threshold (log intensity).
    #[arg(long, default_value_t = 0.2)]
    pub theta_on: f64,
    /// OFF contrast threshold (log intensity).
    #[arg(long, default_value_t = 0.2)]
    pub theta_off: f64,
    /// Per-pixel threshold mismatch, relative standard deviation.
    #[arg(long, default_value_t = 0.03)]
    pub theta_sigma: f64,
    /// Refractory period, nanoseconds.
    #[arg(long, default_value_t = 0)]
    pub refractory_ns: i64,
    /// Intensity floor before the log: `L = ln(max(I * light_scale, log_floor))`.
    #[arg(long, default_value_t = 1e-4)]
    pub log_floor: f64,
    /// Largest image motion between two samples, pixels.
    #[arg(long, default_value_t = 0.25)]
    pub max_shift_px: f64,
    /// Longest sampling step, nanoseconds (the scene is also sampled at least this often when it
    /// does not move).
    #[arg(long, default_value_t = 1_000_000)]
    pub max_step_ns: i64,
    /// Seed of the mismatch draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl Default for DvsConfig {
    fn default() -> Self {
        DvsConfig {
            width: 346,
            height: 260,
            theta_on: 0.2,
            theta_off: 0.2,
            theta_sigma: 0.03,
            refractory_ns: 0,
            log_floor: 1e-4,
            max_shift_px: 0.25,
            max_step_ns: 1_000_000,
            seed: 0,
        }
    }
}

/// A setting out of its range. The message names the setting and the value.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("event camera: `{key}` = {value} is invalid: {why}")]
pub struct ConfigError {
    /// The setting.
    pub key: &'static str,
    /// Its value.
    pub value: String,
    /// What is wrong.
    pub why: &'static str,
}

impl DvsConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |key, value: String, why| Err(ConfigError { key, value, why });
        if self.width == 0 || self.width > usize::from(u16::MAX) {
            return bad("width", self.width.to_string(), "must be in 1..=65535");
        }
        if self.height == 0 || self.height > usize::from(u16::MAX) {
            return bad("height", self.height.to_string(), "must be in 1..=65535");
        }
        for (key, v) in [("theta-on", self.theta_on), ("theta-off", self.theta_off)] {
            if !(v.is_finite() && v >= MIN_THRESHOLD) {
                return bad(key, v.to_string(), "must be finite and >= 0.01");
            }
        }
        if !(self.theta_sigma.is_finite() && self.theta_sigma >= 0.0) {
            return bad(
                "theta-sigma",
                self.theta_sigma.to_string(),
                "must be finite and >= 0",
            );
        }
        if self.refractory_ns < 0 {
            return bad(
                "refractory-ns",
                self.refractory_ns.to_string(),
                "must be >= 0",
            );
        }
        if !(self.log_floor.is_finite() && self.log_floor > 0.0) {
            return bad(
                "log-floor",
                self.log_floor.to_string(),
                "must be finite and > 0",
            );
        }
        if !(self.max_shift_px.is_finite() && self.max_shift_px > 0.0) {
            return bad(
                "max-shift-px",
                self.max_shift_px.to_string(),
                "must be finite and > 0",
            );
        }
        if self.max_step_ns <= 0 {
            return bad("max-step-ns", self.max_step_ns.to_string(), "must be > 0");
        }
        Ok(())
    }
}

/// The event camera looking at a scene.
pub struct EventCamera {
    scene: Scene,
    cfg: DvsConfig,
    step_ns: i64,
    theta_on: Vec<f32>,
    theta_off: Vec<f32>,
    reference: Vec<f32>,
    last_event_ns: Vec<i64>,
    /// Log intensity at `t_ns`.
    log_now: Vec<f32>,
    log_next: Vec<f32>,
    frame: Array2<f32>,
    t_ns: i64,
    scratch: Vec<Event>,
}

impl EventCamera {
    /// A camera whose reference levels are the scene at `t_start_ns`.
    pub fn new(scene: Scene, cfg: DvsConfig, t_start_ns: i64) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let n = cfg.width * cfg.height;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let normal = Normal::new(0.0, cfg.theta_sigma).map_err(|_| ConfigError {
            key: "theta-sigma",
            value: cfg.theta_sigma.to_string(),
            why: "not a valid standard deviation",
        })?;
        let mut draw = |theta: f64| -> Vec<f32> {
            (0..n)
                .map(|_| (theta * (1.0 + normal.sample(&mut rng))).max(MIN_THRESHOLD) as f32)
                .collect()
        };
        let theta_on = draw(cfg.theta_on);
        let theta_off = draw(cfg.theta_off);
        let scale = cfg.width as f64 / scene.width().max(1) as f64;
        let speed = scene.max_speed_px_per_s() * scale;
        let step_ns = if speed > 0.0 {
            ((cfg.max_shift_px / speed) * 1e9)
                .floor()
                .clamp(1.0, cfg.max_step_ns as f64) as i64
        } else {
            cfg.max_step_ns
        };
        let mut cam = EventCamera {
            frame: Array2::zeros((cfg.height, cfg.width)),
            scene,
            step_ns,
            theta_on,
            theta_off,
            reference: vec![0.0; n],
            last_event_ns: vec![i64::MIN; n],
            log_now: vec![0.0; n],
            log_next: vec![0.0; n],
            t_ns: t_start_ns,
            scratch: Vec::new(),
            cfg,
        };
        cam.sample_log(t_start_ns);
        cam.log_now.copy_from_slice(&cam.log_next);
        cam.reference.copy_from_slice(&cam.log_now);
        Ok(cam)
    }

    /// The sampling step, nanoseconds.
    pub fn step_ns(&self) -> i64 {
        self.step_ns
    }

    /// Simulated time so far.
    pub fn time_ns(&self) -> i64 {
        self.t_ns
    }

    /// The scene being watched.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    fn sample_log(&mut self, t_ns: i64) {
        self.scene.render_into(t_ns, self.frame.view_mut());
        let ls = self.scene.light_scale() as f32;
        let floor = self.cfg.log_floor as f32;
        for (l, &i) in self.log_next.iter_mut().zip(self.frame.iter()) {
            *l = (i * ls).max(floor).ln();
        }
    }

    /// Simulates up to `t_end_ns` and returns the events of `[time_ns(), t_end_ns)` as a batch.
    pub fn advance_to(&mut self, t_end_ns: i64, seq: u64) -> EventBatch {
        let mut batch =
            EventBatch::empty(self.cfg.width, self.cfg.height, self.t_ns, t_end_ns, seq);
        while self.t_ns < t_end_ns {
            let t_b = (self.t_ns + self.step_ns).min(t_end_ns);
            self.sample_log(t_b);
            self.scratch.clear();
            self.emit_step(self.t_ns, t_b);
            // Events of one step come pixel by pixel; the batch is in time order.
            self.scratch.sort_by_key(|e| e.t_ns);
            for e in &self.scratch {
                batch.push(*e);
            }
            std::mem::swap(&mut self.log_now, &mut self.log_next);
            self.t_ns = t_b;
        }
        batch
    }

    /// Emits every crossing of the linear log-intensity path between `t_a` and `t_b`.
    fn emit_step(&mut self, t_a: i64, t_b: i64) {
        let w = self.cfg.width;
        let refractory = self.cfg.refractory_ns;
        let dt = (t_b - t_a) as f64;
        for i in 0..self.reference.len() {
            let (la, lb) = (f64::from(self.log_now[i]), f64::from(self.log_next[i]));
            let mut r = f64::from(self.reference[i]);
            let (on, off) = (f64::from(self.theta_on[i]), f64::from(self.theta_off[i]));
            loop {
                let (level, polarity) = if lb >= r + on {
                    (r + on, 1i8)
                } else if lb <= r - off {
                    (r - off, -1i8)
                } else {
                    break;
                };
                // Time at which the linear path reaches `level`; a level already passed at t_a
                // (left behind during a refractory period) fires at t_a.
                let frac = if lb != la {
                    ((level - la) / (lb - la)).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                // Events of this step stay inside [t_a, t_b): a crossing exactly at t_b is
                // stamped one nanosecond earlier.
                let mut t = (t_a + (frac * dt).round() as i64).min(t_b - 1);
                let free_at = self.last_event_ns[i].saturating_add(refractory);
                if t < free_at {
                    if free_at >= t_b {
                        break; // still in reset at the end of the step: the reference waits
                    }
                    t = free_at;
                }
                r = level;
                self.last_event_ns[i] = t;
                self.scratch.push(Event {
                    t_ns: t,
                    x: (i % w) as u16,
                    y: (i / w) as u16,
                    polarity,
                });
            }
            self.reference[i] = r as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(yaml_motion: &str, light: f64) -> Scene {
        let yaml = format!(
            "width: 32\nheight: 16\nduration_ms: 20\nlight_scale: {light}\nsamples_per_pixel: 1\n\
             texture:\n  kind: grating\n  period_px: 16\n{yaml_motion}"
        );
        Scene::from_yaml_str(&yaml, "test", None).expect("scene")
    }

    fn cfg() -> DvsConfig {
        DvsConfig {
            width: 32,
            height: 16,
            theta_sigma: 0.0,
            ..Default::default()
        }
    }

    #[test]
    fn static_scene_is_silent() {
        let mut cam = EventCamera::new(scene("", 1.0), cfg(), 0).unwrap();
        assert!(cam.advance_to(10_000_000, 0).is_empty());
    }

    #[test]
    fn moving_scene_fires_and_events_are_ordered_and_inside() {
        let mut cam =
            EventCamera::new(scene("motion:\n  vx_px_s: 500.0\n", 1.0), cfg(), 0).unwrap();
        let b = cam.advance_to(5_000_000, 3);
        assert!(b.len() > 100, "{} events", b.len());
        b.validate("test").unwrap();
        assert!(b.polarity.iter().any(|&p| p == 1) && b.polarity.iter().any(|&p| p == -1));
        assert_eq!((b.t_start_ns, b.t_end_ns, b.seq), (0, 5_000_000, 3));
    }

    /// Summing the events times the threshold gives back the change of log intensity, to within
    /// one threshold per pixel: no crossing is lost.
    #[test]
    fn event_sum_tracks_log_intensity() {
        let c = cfg();
        let s = scene("motion:\n  vx_px_s: 300.0\n", 1.0);
        let mut cam = EventCamera::new(s.clone(), c.clone(), 0).unwrap();
        let b = cam.advance_to(8_000_000, 0);
        let start = s.render(0, 16, 32);
        let end = s.render(8_000_000, 16, 32);
        let mut sum = Array2::<f64>::zeros((16, 32));
        for i in 0..b.len() {
            let e = b.get(i);
            sum[[usize::from(e.y), usize::from(e.x)]] += f64::from(e.polarity) * c.theta_on;
        }
        for ((y, x), &s) in sum.indexed_iter() {
            let dl =
                f64::from(end[[y, x]].max(1e-4)).ln() - f64::from(start[[y, x]].max(1e-4)).ln();
            assert!(
                (s - dl).abs() <= c.theta_on + 1e-3,
                "pixel ({x},{y}): events {s} vs dL {dl}"
            );
        }
    }

    #[test]
    fn refractory_period_spaces_events() {
        let mut c = cfg();
        c.refractory_ns = 1_000_000;
        let mut cam = EventCamera::new(scene("motion:\n  vx_px_s: 2000.0\n", 1.0), c, 0).unwrap();
        let b = cam.advance_to(10_000_000, 0);
        let mut last = std::collections::HashMap::new();
        for i in 0..b.len() {
            let e = b.get(i);
            if let Some(prev) = last.insert((e.x, e.y), e.t_ns) {
                assert!(
                    e.t_ns - prev >= 1_000_000,
                    "pixel ({},{}) fired after {} ns",
                    e.x,
                    e.y,
                    e.t_ns - prev
                );
            }
        }
    }

    #[test]
    fn deterministic_for_a_seed() {
        let mk = |seed| {
            let c = DvsConfig { seed, ..cfg() };
            let c = DvsConfig {
                theta_sigma: 0.1,
                ..c
            };
            EventCamera::new(scene("motion:\n  vx_px_s: 400.0\n", 1.0), c, 0)
                .unwrap()
                .advance_to(3_000_000, 0)
        };
        assert_eq!(mk(1), mk(1));
        assert_ne!(mk(1), mk(2));
    }

    #[test]
    fn bad_settings_name_the_key() {
        let c = DvsConfig {
            theta_on: 0.0,
            ..cfg()
        };
        let e = EventCamera::new(scene("", 1.0), c, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("theta-on") && e.contains('0'), "{e}");
    }
}
