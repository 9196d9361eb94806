//! The spike camera's noise beyond the paper's two terms, each switchable, and the named camera
//! profiles that set them.
//!
//! Every term is a node argument (`--threshold-jitter 0.05`) and a field of a profile
//! (`--profile vidar`, or `--profile my-camera.yml`); an argument given on the command line wins
//! over the profile's value. At 0 a term is off, and with every term off the camera is the paper's
//! model bit for bit.
//!
//! | term | argument | model |
//! |---|---|---|
//! | photon shot noise | `--electrons-per-phi N` | the charge of one threshold is `N` photo-electrons with Poisson arrivals, so an interval's charge varies by `1 / sqrt(N)` relative (0 = off) |
//! | per-fire threshold jitter | `--threshold-jitter s` | the threshold of each interval is `phi (1 + s z)` |
//! | per-pixel threshold offset | `--threshold-offset s` | each pixel's threshold is `phi (1 + s z_i)`, drawn once (fixed pattern) |
//! | photo-response non-uniformity | `--prnu s` | each pixel's light is multiplied by `1 + s z_i`, drawn once |
//! | dark current | `--dark-current-hz d`, `--dark-current-spread s` | a pixel in the dark fires at `d_i` Hz, `d_i` log-normal with mean `d` and log standard deviation `s` (fixed pattern) |
//! | reset delay | `--reset-delay-ticks r` | after a fire the pixel does not integrate for `r` of a tick: the light of that time is lost |
//! | random spikes | `--random-spike-hz f` | each pixel reads a spike it did not fire, at random, `f` times a second on average (a Bernoulli draw each tick, probability `f / rate_hz`): readout glitches that leave the pixel's charge as it was |
//!
//! Shot noise and jitter act per interval, not per tick: the time to collect `N` electrons under
//! Poisson arrivals is Gamma-distributed, and an integrator whose threshold is drawn afresh for
//! each interval with relative standard deviation `1 / sqrt(N)` has the same mean and variance
//! of the interval. The two combine into one draw per interval, `sigma = sqrt(s^2 + 1 / N)`, from
//! a triangular distribution (the sum of two uniforms, bounded to `phi (1 +- sqrt(6) sigma)`;
//! `sigma` is at most [`MAX_FIRE_SIGMA`], so a threshold stays above 2% of `phi`). The draws come
//! from a per-pixel linear congruential generator seeded from the camera's seed: each tick takes
//! the top two bytes of its state as the two uniforms (511 levels across `+- sqrt(6) sigma`).
//!
//! A per-pixel threshold offset is simulated as its equivalent gain: a pixel whose threshold is
//! `phi (1 + o)` integrating `L` fires exactly as a pixel of threshold `phi` integrating
//! `L / (1 + o)`.
//!
//! The values of the `scsim` profile are those of SCSim's simulator (Hu et al., "SCSim: A
//! Realistic Spike Cameras Simulator", ICME 2024, `v2s.py`), mapped onto these terms in
//! `docs/camera.md`; `vidar` is fitted to a real Vidar recording by `neuspike calibrate`.

use crate::ConfigError;
use std::path::Path;

/// The largest combined per-interval standard deviation, relative to `phi`: the triangular draw
/// reaches `sqrt(6) sigma`, so the smallest threshold is `phi (1 - 0.98)`.
pub const MAX_FIRE_SIGMA: f64 = 0.4;

/// The standard deviation of the sum of two independent uniform integers on `0..=255`, the raw
/// triangular draw: `sqrt(2 (256^2 - 1) / 12)`.
pub const TRIANGLE_STD: f32 = 104.510_765;

/// The noise terms, each 0 when off. See the module documentation for the model of each.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Noise {
    /// Photo-electrons per threshold (shot noise); 0 = no shot noise.
    pub electrons_per_phi: f64,
    /// Per-interval threshold jitter, relative standard deviation.
    pub threshold_jitter: f64,
    /// Per-pixel threshold offset (fixed pattern), relative standard deviation.
    pub threshold_offset: f64,
    /// Per-pixel gain (photo-response non-uniformity), relative standard deviation.
    pub prnu: f64,
    /// Mean firing rate of a pixel in the dark from dark current alone, Hz.
    pub dark_current_hz: f64,
    /// Log standard deviation of the per-pixel dark current (fixed pattern).
    pub dark_current_spread: f64,
    /// Light lost after each fire, in ticks of integration.
    pub reset_delay_ticks: f64,
    /// Spikes read at random, independent of the light and of the pixel's charge, per pixel, Hz.
    pub random_spike_hz: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise::OFF
    }
}

impl Noise {
    /// Every term off: the paper's model.
    pub const OFF: Noise = Noise {
        electrons_per_phi: 0.0,
        threshold_jitter: 0.0,
        threshold_offset: 0.0,
        prnu: 0.0,
        dark_current_hz: 0.0,
        dark_current_spread: 0.0,
        reset_delay_ticks: 0.0,
        random_spike_hz: 0.0,
    };

    /// SCSim's values on these terms (`docs/camera.md` gives the mapping): shot noise of 50,000
    /// photons per full-light step, threshold noise 0.00636 V and offset 0.0497 V on a 1.0924 V
    /// swing, gain 5.77%, dark current 0.4442 +- 0.1731 (93.5 Hz at 20 kHz), reset 100 ns of a
    /// 50 us readout.
    pub const SCSIM: Noise = Noise {
        electrons_per_phi: 50_000.0,
        threshold_jitter: 0.005_82,
        threshold_offset: 0.045_5,
        prnu: 0.057_7,
        dark_current_hz: 93.5,
        dark_current_spread: 0.38,
        reset_delay_ticks: 0.002,
        random_spike_hz: 0.0,
    };

    /// The combined relative standard deviation of an interval's threshold:
    /// `sqrt(threshold_jitter^2 + 1 / electrons_per_phi)` (no shot term at 0 electrons).
    pub fn fire_sigma(&self) -> f64 {
        let shot = if self.electrons_per_phi > 0.0 {
            1.0 / self.electrons_per_phi
        } else {
            0.0
        };
        (self.threshold_jitter * self.threshold_jitter + shot).sqrt()
    }

    /// Whether the per-fire part (jitter, shot noise, reset delay) is on: the camera then runs the
    /// noisy kernel.
    pub fn per_fire(&self) -> bool {
        self.fire_sigma() > 0.0 || self.reset_delay_ticks > 0.0
    }

    /// Checks every value: finite, `>= 0`, the combined sigma at most [`MAX_FIRE_SIGMA`], the
    /// reset delay below one tick.
    pub fn check(&self) -> Result<(), ConfigError> {
        let fields = [
            ("electrons-per-phi", self.electrons_per_phi),
            ("threshold-jitter", self.threshold_jitter),
            ("threshold-offset", self.threshold_offset),
            ("prnu", self.prnu),
            ("dark-current-hz", self.dark_current_hz),
            ("dark-current-spread", self.dark_current_spread),
            ("reset-delay-ticks", self.reset_delay_ticks),
            ("random-spike-hz", self.random_spike_hz),
        ];
        for (key, v) in fields {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError {
                    key,
                    value: v.to_string(),
                    why: "must be finite and >= 0",
                });
            }
        }
        if self.fire_sigma() > MAX_FIRE_SIGMA {
            return Err(ConfigError {
                key: "threshold-jitter",
                value: format!(
                    "{} (with shot noise {})",
                    self.fire_sigma(),
                    self.electrons_per_phi
                ),
                why: "the combined per-fire sigma must be <= 0.4",
            });
        }
        for (key, v) in [
            ("threshold-offset", self.threshold_offset),
            ("prnu", self.prnu),
        ] {
            if v > 1.0 {
                return Err(ConfigError {
                    key,
                    value: v.to_string(),
                    why: "must be <= 1",
                });
            }
        }
        if self.dark_current_spread > 3.0 {
            return Err(ConfigError {
                key: "dark-current-spread",
                value: self.dark_current_spread.to_string(),
                why: "must be <= 3 (log standard deviation)",
            });
        }
        if self.reset_delay_ticks >= 1.0 {
            return Err(ConfigError {
                key: "reset-delay-ticks",
                value: self.reset_delay_ticks.to_string(),
                why: "must be < 1 tick",
            });
        }
        Ok(())
    }
}

/// A camera profile as a file holds it: the noise terms and where they come from.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileFile {
    /// Format version, 1.
    pub version: u32,
    /// The profile's name.
    pub name: String,
    /// Where the values come from (the command and data that fitted them, or a citation).
    pub provenance: String,
    /// The terms.
    pub noise: Noise,
}

/// The `vidar` profile, fitted by `neuspike calibrate` to the real Vidar recording.
pub const VIDAR_YAML: &str = include_str!("../profiles/vidar.yml");

/// The names of the built-in profiles.
pub const PROFILES: [&str; 3] = ["paper", "scsim", "vidar"];

/// A profile larger than this is refused before it is read.
const MAX_PROFILE_BYTES: u64 = 64 * 1024;

/// A profile by name (`paper`, `scsim`, `vidar`) or from a YAML file.
///
/// # Errors
/// An unknown name that is no readable file, a file too large, not YAML of the profile's shape,
/// of another version, or with a value out of range; the message names the file and field.
pub fn profile(name: &str) -> Result<Noise, String> {
    match name {
        "paper" => return Ok(Noise::OFF),
        "scsim" => return Ok(Noise::SCSIM),
        "vidar" => return parse_profile(VIDAR_YAML, "built-in profile `vidar`").map(|p| p.noise),
        _ => {}
    }
    let path = Path::new(name);
    let size = std::fs::metadata(path)
        .map_err(|e| {
            format!(
                "spike camera: --profile {name}: neither a built-in profile ({}) nor a readable file: {e}",
                PROFILES.join(", ")
            )
        })?
        .len();
    if size > MAX_PROFILE_BYTES {
        return Err(format!(
            "{}: {size} bytes, a profile is at most {MAX_PROFILE_BYTES}",
            path.display()
        ));
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    parse_profile(&text, &path.display().to_string()).map(|p| p.noise)
}

/// Parses and checks a profile's YAML; `origin` names it in errors.
///
/// # Errors
/// Not YAML of the profile's shape, a version other than 1, a value out of range.
pub fn parse_profile(text: &str, origin: &str) -> Result<ProfileFile, String> {
    let p: ProfileFile = serde_yaml::from_str(text).map_err(|e| {
        let e = e.to_string();
        format!("{origin}: {}", e.lines().next().unwrap_or_default())
    })?;
    if p.version != 1 {
        return Err(format!(
            "{origin}: `version` = {}: this build reads version 1",
            p.version
        ));
    }
    p.noise.check().map_err(|e| format!("{origin}: {e}"))?;
    Ok(p)
}

/// The noise arguments of a camera: a profile and per-term overrides.
#[derive(Clone, Debug, PartialEq, clap::Args)]
pub struct NoiseArgs {
    /// Camera profile: `paper` (the paper's model: only the random initial charge and the ISI
    /// cap), `scsim` (SCSim's noise values), `vidar` (fitted to a real Vidar), or a profile file.
    #[arg(long, default_value = "paper")]
    pub profile: String,
    /// Shot noise: photo-electrons per threshold (0 = off). Overrides the profile.
    #[arg(long)]
    pub electrons_per_phi: Option<f64>,
    /// Per-interval threshold jitter, relative standard deviation. Overrides the profile.
    #[arg(long)]
    pub threshold_jitter: Option<f64>,
    /// Per-pixel threshold offset, relative standard deviation. Overrides the profile.
    #[arg(long)]
    pub threshold_offset: Option<f64>,
    /// Per-pixel gain (PRNU), relative standard deviation. Overrides the profile.
    #[arg(long)]
    pub prnu: Option<f64>,
    /// Dark current: a dark pixel's mean firing rate, Hz. Overrides the profile.
    #[arg(long)]
    pub dark_current_hz: Option<f64>,
    /// Dark current's fixed pattern: log standard deviation across pixels. Overrides the profile.
    #[arg(long)]
    pub dark_current_spread: Option<f64>,
    /// Light lost after each fire, ticks. Overrides the profile.
    #[arg(long)]
    pub reset_delay_ticks: Option<f64>,
    /// Spikes read at random per pixel, Hz (below the plane rate); overrides the profile.
    #[arg(long)]
    pub random_spike_hz: Option<f64>,
}

impl Default for NoiseArgs {
    fn default() -> Self {
        NoiseArgs::from(Noise::OFF)
    }
}

impl From<Noise> for NoiseArgs {
    /// Arguments that give exactly `noise` (on the `paper` profile).
    fn from(n: Noise) -> Self {
        NoiseArgs {
            profile: "paper".into(),
            electrons_per_phi: Some(n.electrons_per_phi),
            threshold_jitter: Some(n.threshold_jitter),
            threshold_offset: Some(n.threshold_offset),
            prnu: Some(n.prnu),
            dark_current_hz: Some(n.dark_current_hz),
            dark_current_spread: Some(n.dark_current_spread),
            reset_delay_ticks: Some(n.reset_delay_ticks),
            random_spike_hz: Some(n.random_spike_hz),
        }
    }
}

impl NoiseArgs {
    /// The profile with the overrides applied, checked.
    ///
    /// # Errors
    /// The profile cannot be loaded, or a value is out of range.
    pub fn resolve(&self) -> Result<Noise, String> {
        let mut n = profile(&self.profile)?;
        let set = |v: &mut f64, o: Option<f64>| {
            if let Some(o) = o {
                *v = o;
            }
        };
        set(&mut n.electrons_per_phi, self.electrons_per_phi);
        set(&mut n.threshold_jitter, self.threshold_jitter);
        set(&mut n.threshold_offset, self.threshold_offset);
        set(&mut n.prnu, self.prnu);
        set(&mut n.dark_current_hz, self.dark_current_hz);
        set(&mut n.dark_current_spread, self.dark_current_spread);
        set(&mut n.reset_delay_ticks, self.reset_delay_ticks);
        set(&mut n.random_spike_hz, self.random_spike_hz);
        n.check().map_err(|e| e.to_string())?;
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_profiles_load_and_overrides_win() {
        assert_eq!(profile("paper").unwrap(), Noise::OFF);
        assert!(!Noise::OFF.per_fire());
        let v = profile("vidar").unwrap();
        assert!(v.per_fire(), "{v:?}");
        let args = NoiseArgs {
            profile: "scsim".into(),
            prnu: Some(0.2),
            ..NoiseArgs::from(Noise::OFF)
        };
        // Overrides from `From` are all set: only the profile name changed, so every term is 0
        // except the one given.
        assert_eq!(args.resolve().unwrap().prnu, 0.2);
        let only_profile = NoiseArgs {
            profile: "scsim".into(),
            electrons_per_phi: None,
            threshold_jitter: None,
            threshold_offset: None,
            prnu: Some(0.2),
            dark_current_hz: None,
            dark_current_spread: None,
            reset_delay_ticks: None,
            random_spike_hz: None,
        };
        let n = only_profile.resolve().unwrap();
        assert_eq!(n.prnu, 0.2);
        assert_eq!(n.dark_current_hz, Noise::SCSIM.dark_current_hz);
    }

    #[test]
    fn bad_profiles_and_values_are_named() {
        let e = profile("no-such-profile-or-file").unwrap_err();
        assert!(
            e.contains("no-such-profile-or-file") && e.contains("vidar"),
            "{e}"
        );
        let e =
            parse_profile("version: 2\nname: x\nprovenance: y\nnoise: {}\n", "p.yml").unwrap_err();
        assert!(e.contains("p.yml") && e.contains("version"), "{e}");
        let e = parse_profile(
            "version: 1\nname: x\nprovenance: y\nnoise: { prnu: -1 }\n",
            "p.yml",
        )
        .unwrap_err();
        assert!(
            e.contains("p.yml") && e.contains("prnu") && e.contains("-1"),
            "{e}"
        );
        let e = parse_profile(
            "version: 1\nname: x\nprovenance: y\nnoise: { gain: 1 }\n",
            "p.yml",
        )
        .unwrap_err();
        assert!(e.contains("p.yml") && e.contains("gain"), "{e}");
        let big = Noise {
            threshold_jitter: 0.5,
            ..Noise::OFF
        };
        assert!(big.check().unwrap_err().to_string().contains("0.4"));
        let nan = Noise {
            dark_current_hz: f64::NAN,
            ..Noise::OFF
        };
        assert!(
            nan.check()
                .unwrap_err()
                .to_string()
                .contains("dark-current-hz")
        );
    }

    #[test]
    fn a_profile_round_trips_through_yaml() {
        let p = ProfileFile {
            version: 1,
            name: "mine".into(),
            provenance: "test".into(),
            noise: Noise::SCSIM,
        };
        let text = serde_yaml::to_string(&p).unwrap();
        assert_eq!(parse_profile(&text, "t").unwrap(), p);
    }
}
