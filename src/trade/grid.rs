//! The scenes of the trade bench: the paper's 5 light scales x 5 speeds at full sensor size, and
//! the extreme corners, each seen through several textures drawn with fixed seeds.

use neuspike_scene::Scene;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use neuspike_dataset::{LIGHT_SCALES, SPEEDS_PX_S};

/// Sensor width of every scene (the spike camera's; the DVS sees the same view at the same size,
/// as the event methods need).
pub const WIDTH: usize = 400;
/// Sensor height.
pub const HEIGHT: usize = 250;
/// Spike plane rate, Hz.
pub const RATE_HZ: f64 = 20_000.0;
/// Planes between two windows (align's stride): a frame every millisecond.
pub const STRIDE_PLANES: u64 = 20;
/// The windows scored, by reference plane: four frames a millisecond apart, late enough that
/// the stateful methods (TFSTP, HF, CF, the fusion) have run 15 windows before the first.
pub const SCORED_PLANES: [u64; 4] = [300, 320, 340, 360];
/// Planes simulated: the last scored window of the longest TFP (256 planes) ends at plane
/// 360 + 127.
pub const PLANES: u64 = 488;
/// The instant the `static-to-fast` scene starts moving: between the second and third scored
/// frames, so that two are still and two move (and every long window straddles the change).
pub const MOTION_START_PLANE: u64 = 330;

/// What the textures are drawn from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TextureSet {
    /// Textures never used in training: the procedural generators `noise`, `shapes` and
    /// `strokes` with odd seeds (the held-out stream of `neuspike dataset`).
    HeldOut,
    /// Training textures: even seeds, and the parametric generators too (for fitting a policy).
    Train,
}

impl TextureSet {
    /// The name in the CSV.
    pub fn as_str(self) -> &'static str {
        match self {
            TextureSet::HeldOut => "held-out",
            TextureSet::Train => "train",
        }
    }
}

/// A kind of scene: a cell of the grid or an extreme corner.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneClass {
    /// Its name in the CSV: `light0.25-speed1000`, or the corner's name.
    pub name: String,
    /// The light scale (a pixel of luminance 1 fires `light` times a tick).
    pub light: f64,
    /// Speed of the view, scene pixels per second.
    pub speed_px_s: f64,
    /// A corner, not a grid cell.
    pub corner: Option<Corner>,
}

/// The extreme scenes, beyond the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Corner {
    /// Almost no light: a pixel of luminance 1 fires once every 10,000 ticks.
    NoLight,
    /// Light that saturates the spike camera: every pixel brighter than 1/4 fires every tick.
    Saturated,
    /// A 6-decade lighting ramp across the view (dim left, bright right), panning.
    Hdr,
    /// Fine high-contrast texture at the grid's top speed, seen by a DVS with a low threshold.
    EventFlood,
    /// A still scene in very dim light (2.5x darker than the grid's darkest row).
    StaticDark,
    /// Still, then the grid's top speed from plane 330 on.
    StaticToFast,
}

impl Corner {
    /// Every corner, in the order of the tables.
    pub const ALL: [Corner; 6] = [
        Corner::NoLight,
        Corner::Saturated,
        Corner::Hdr,
        Corner::EventFlood,
        Corner::StaticDark,
        Corner::StaticToFast,
    ];

    /// Its name.
    pub fn as_str(self) -> &'static str {
        match self {
            Corner::NoLight => "no-light",
            Corner::Saturated => "saturated",
            Corner::Hdr => "hdr-6-decades",
            Corner::EventFlood => "event-flood",
            Corner::StaticDark => "static-dark",
            Corner::StaticToFast => "static-to-fast",
        }
    }

    fn class(self) -> SceneClass {
        let (light, speed) = match self {
            Corner::NoLight => (1e-4, 1_000.0),
            Corner::Saturated => (4.0, 1_000.0),
            Corner::Hdr => (1.0, 1_000.0),
            Corner::EventFlood => (1.0, 8_000.0),
            Corner::StaticDark => (0.02, 0.0),
            Corner::StaticToFast => (0.5, 8_000.0),
        };
        SceneClass {
            name: self.as_str().to_string(),
            light,
            speed_px_s: speed,
            corner: Some(self),
        }
    }
}

impl SceneClass {
    /// The grid cell of `light` and `speed`.
    pub fn cell(light: f64, speed_px_s: f64) -> SceneClass {
        SceneClass {
            name: format!("light{light}-speed{speed_px_s}"),
            light,
            speed_px_s,
            corner: None,
        }
    }

    /// The DVS contrast threshold of the scene: 0.2, rising in the dark as a DVS's effective
    /// sensitivity falls (`neuspike dataset`'s rule, `0.2 (1 + 0.25 ln(1 / light))` for light
    /// below 1; the logarithm's argument is at least 1), and 0.05 for the event flood.
    pub fn theta(&self) -> f64 {
        if self.corner == Some(Corner::EventFlood) {
            return 0.05;
        }
        0.2 * (1.0 + 0.25 * (1.0 / self.light).max(1.0).ln())
    }

    /// The group the plots and tables gather it in: `dark`/`bright` x `static`/`slow`/`fast`
    /// for grid cells, the corner's own name otherwise.
    pub fn group(&self) -> String {
        if let Some(c) = self.corner {
            return c.as_str().to_string();
        }
        let light = if self.light <= 0.1 { "dark" } else { "bright" };
        let speed = if self.speed_px_s == 0.0 {
            "static"
        } else if self.speed_px_s < 3_000.0 {
            "slow"
        } else {
            "fast"
        };
        format!("{light} {speed}")
    }
}

/// The grid: every light x speed cell, then the corners. `quick` keeps 3 x 3 cells (light 0.05,
/// 0.25 and 1; speed 0, 1,000 and 8,000 px/s) and every corner.
pub fn classes(quick: bool) -> Vec<SceneClass> {
    let pick = |all: &[f64], keep: &[usize]| -> Vec<f64> {
        if quick {
            keep.iter().map(|&i| all[i]).collect()
        } else {
            all.to_vec()
        }
    };
    let mut out = Vec::new();
    for light in pick(&LIGHT_SCALES, &[0, 2, 4]) {
        for speed in pick(&SPEEDS_PX_S, &[0, 2, 4]) {
            out.push(SceneClass::cell(light, speed));
        }
    }
    out.extend(Corner::ALL.iter().map(|c| c.class()));
    out
}

/// One scene of a class: its YAML and its texture's label (`kind:seed`).
pub fn scene(class: &SceneClass, set: TextureSet, texture: usize) -> eyre::Result<(Scene, String)> {
    // One stream per (set, texture index): the same texture in every class, so that classes
    // differ only in light and motion.
    let mut rng = ChaCha8Rng::seed_from_u64(0x7ade);
    rng.set_stream(
        match set {
            TextureSet::HeldOut => 1,
            TextureSet::Train => 2,
        } * (1 << 32)
            + texture as u64,
    );
    let pool: &[&str] = match set {
        TextureSet::HeldOut => &["noise", "shapes", "strokes"],
        TextureSet::Train => &["noise", "shapes", "strokes", "grating", "checkerboard"],
    };
    let kind = match class.corner {
        Some(Corner::EventFlood) => "noise",
        _ => pool[texture % pool.len()],
    };
    let extra = match (class.corner, kind) {
        (Some(Corner::EventFlood), _) => "beta: 1.0".to_string(),
        (_, "noise") => format!("beta: {:.3}", rng.random_range(1.5..3.0)),
        (_, "shapes") => format!("count: {}", rng.random_range(10..120)),
        (_, "grating") => format!(
            "period_px: {:.2}, angle_deg: {:.1}",
            rng.random_range(4.0..48.0),
            rng.random_range(0.0..180.0)
        ),
        (_, "checkerboard") => format!("square_px: {:.2}", rng.random_range(4.0..40.0)),
        _ => String::new(),
    };
    let contrast: f64 = rng.random_range(0.6..1.0);
    let angle = rng.random_range(0.0..360.0f64).to_radians();
    // Seeds: odd for held-out textures, even for training ones, as `neuspike dataset` draws them.
    let seed = 2 * (rng.random::<u64>() >> 2)
        + match set {
            TextureSet::HeldOut => 1,
            TextureSet::Train => 0,
        };
    let period_ns = (1e9 / RATE_HZ).round() as u64;
    let duration_ns = period_ns * (PLANES + 4);
    let start_ns = match class.corner {
        Some(Corner::StaticToFast) => period_ns * MOTION_START_PLANE,
        _ => 0,
    };
    let light_map = match class.corner {
        Some(Corner::Hdr) => "light: { gain_map: { kind: horizontal, decades: 6.0 } }\n",
        _ => "",
    };
    let sep = if extra.is_empty() { "" } else { ", " };
    let yaml = format!(
        "width: {WIDTH}\nheight: {HEIGHT}\nduration_ns: {duration_ns}\nseed: {seed}\n\
         light_scale: {light}\ntexture: {{ kind: {kind}, contrast: {contrast:.3}{sep}{extra} }}\n\
         motion: {{ vx_px_s: {vx}, vy_px_s: {vy}, start_ns: {start_ns} }}\n{light_map}",
        light = class.light,
        vx = class.speed_px_s * angle.cos(),
        vy = class.speed_px_s * angle.sin(),
    );
    let scene = Scene::from_yaml_str(&yaml, &format!("bench scene {}", class.name), None)?;
    Ok((scene, format!("{kind}:{seed}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_holds_every_cell_and_corner_and_quick_a_subset() {
        let full = classes(false);
        assert_eq!(full.len(), 25 + 6);
        let quick = classes(true);
        assert_eq!(quick.len(), 9 + 6);
        assert!(quick.iter().all(|q| full.contains(q)));
        let names: std::collections::BTreeSet<_> = full.iter().map(|c| &c.name).collect();
        assert_eq!(names.len(), full.len());
    }

    #[test]
    fn textures_are_fixed_per_index_shared_by_classes_and_apart_between_sets() {
        let cls = classes(true);
        let (a, la) = scene(&cls[0], TextureSet::HeldOut, 1).expect("scene");
        let (b, lb) = scene(&cls[1], TextureSet::HeldOut, 1).expect("scene");
        assert_eq!(la, lb);
        assert_eq!(a.render(0, 25, 40), b.render(0, 25, 40));
        let (_, other) = scene(&cls[0], TextureSet::HeldOut, 2).expect("scene");
        assert_ne!(la, other);
        let odd = |l: &str| {
            l.rsplit(':')
                .next()
                .and_then(|s| s.parse::<u64>().ok())
                .map(|s| s % 2)
        };
        for t in 0..6 {
            let (_, h) = scene(&cls[0], TextureSet::HeldOut, t).expect("held out");
            let (_, tr) = scene(&cls[0], TextureSet::Train, t).expect("train");
            assert_eq!(odd(&h), Some(1), "{h}");
            assert_eq!(odd(&tr), Some(0), "{tr}");
        }
        // The static-to-fast corner holds still until its start, then moves.
        let stf = cls
            .iter()
            .find(|c| c.corner == Some(Corner::StaticToFast))
            .expect("corner");
        let (s, _) = scene(stf, TextureSet::HeldOut, 0).expect("scene");
        let period = (1e9 / RATE_HZ) as i64;
        let at = |k: i64| s.render(k * period, 25, 40);
        assert_eq!(at(0), at(MOTION_START_PLANE as i64));
        assert_ne!(
            at(MOTION_START_PLANE as i64),
            at(MOTION_START_PLANE as i64 + 20)
        );
    }
}
