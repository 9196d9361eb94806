//! The scene description as written in YAML, and its validation.
//!
//! Every struct denies unknown fields; every field but `texture` has a default. Parsing (serde)
//! checks shapes and types; [`SceneSpec::validate`] checks ranges and the combinations serde cannot
//! express, and names the offending field and value in its error.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::error::SceneError;

/// Nanoseconds in a second, for times in seconds.
pub(crate) const NS_PER_S: f64 = 1e9;

/// Default view width in scene pixels.
pub const DEFAULT_WIDTH: usize = 400;
/// Default view height in scene pixels.
pub const DEFAULT_HEIGHT: usize = 250;
/// Default duration when neither `duration_ms` nor `duration_ns` is given.
pub const DEFAULT_DURATION_MS: u64 = 50;
/// Default supersampling grid per axis.
pub const DEFAULT_SAMPLES_PER_PIXEL: usize = 2;
/// Largest supersampling grid per axis.
pub const MAX_SAMPLES_PER_PIXEL: usize = 8;
/// Largest view side in scene pixels.
pub const MAX_VIEW_SIDE: usize = 16_384;
/// Default canvas side of procedural textures.
pub const DEFAULT_TEXTURE_SIZE: usize = 512;
/// Smallest canvas side of procedural textures.
pub const MIN_TEXTURE_SIZE: usize = 4;
/// Largest canvas side of procedural textures.
pub const MAX_TEXTURE_SIZE: usize = 8_192;
/// Default floor of texture values (keeps log intensity defined).
pub const DEFAULT_TEXTURE_MIN: f64 = 0.02;
/// Default spectral exponent of `noise` (power ~ 1/f^beta).
pub const DEFAULT_NOISE_BETA: f64 = 2.0;
/// Largest accepted spectral exponent of `noise`.
pub const MAX_NOISE_BETA: f64 = 6.0;
/// Default number of shapes of `shapes`.
pub const DEFAULT_SHAPE_COUNT: usize = 40;
/// Largest number of shapes of `shapes`.
pub const MAX_SHAPE_COUNT: usize = 10_000;
/// Default period of `grating`, in texture pixels.
pub const DEFAULT_GRATING_PERIOD_PX: f64 = 32.0;
/// Default square side of `checkerboard`, in texture pixels.
pub const DEFAULT_SQUARE_PX: f64 = 32.0;
/// Largest accepted gain-map span in decades.
pub const MAX_GAIN_DECADES: f64 = 12.0;

/// A whole scene: view, duration, texture, motion and light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// View width in scene pixels.
    #[serde(default = "default_width")]
    pub width: usize,
    /// View height in scene pixels.
    #[serde(default = "default_height")]
    pub height: usize,
    /// Duration in milliseconds (give at most one of `duration_ms`, `duration_ns`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_ms: Option<u64>,
    /// Duration in nanoseconds (give at most one of `duration_ms`, `duration_ns`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_ns: Option<u64>,
    /// Seed of every random choice of the procedural textures.
    #[serde(default)]
    pub seed: u64,
    /// Overall light level the cameras multiply the luminance by; finite and > 0.
    #[serde(default = "default_light_scale")]
    pub light_scale: f64,
    /// Supersampling grid per axis (1 = pixel centre only), 1..=8.
    #[serde(default = "default_samples_per_pixel")]
    pub samples_per_pixel: usize,
    /// What the scene looks like.
    pub texture: TextureSpec,
    /// How the view moves over the texture.
    #[serde(default)]
    pub motion: MotionSpec,
    /// Optional high-dynamic-range lighting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<LightSpec>,
}

/// The texture: a kind and the parameters of that kind (flat, like the YAML).
///
/// Parameters that do not belong to the kind are rejected by validation, so a typo cannot be
/// silently ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureSpec {
    /// Which generator (or a PNG file).
    pub kind: TextureKind,
    /// Canvas side in texture pixels of procedural textures (default 512); not allowed for png.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<usize>,
    /// Contrast about mid-grey: `t' = 0.5 + contrast * (t - 0.5)`, before the floor (default 1).
    #[serde(default = "default_contrast")]
    pub contrast: f64,
    /// Floor of texture values, in (0, 1) (default 0.02): values are clamped to `[min, 1]`.
    #[serde(default = "default_texture_min")]
    pub min: f64,
    /// `noise`: spectral exponent, power ~ 1/f^beta (default 2), in [0, 6].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
    /// `shapes`: number of discs and rectangles (default 40).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// `grating`: period in texture pixels (default 32).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub period_px: Option<f64>,
    /// `grating`: orientation of the wave vector in degrees (default 0 = vertical bars).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle_deg: Option<f64>,
    /// `checkerboard`: square side in texture pixels (default 32).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub square_px: Option<f64>,
    /// `png`: path of the image, relative paths resolved against the scene file's folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
}

/// The texture generators.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TextureKind {
    /// 1/f^beta Gaussian noise (periodic by construction).
    Noise,
    /// Random grey discs and rotated rectangles on a grey background (drawn with wrap-around).
    Shapes,
    /// Sinusoidal grating (frequency snapped to whole cycles per canvas).
    Grating,
    /// Text-like dark pen strokes on bright paper (drawn with wrap-around).
    Strokes,
    /// Black and white squares (square side snapped so the canvas holds an even count).
    Checkerboard,
    /// A PNG file, mirror-tiled.
    Png,
}

/// Constant-rate motion of the view over the texture. All rates default to 0.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    /// Horizontal image velocity in texture pixels per second (positive: content moves right).
    #[serde(default)]
    pub vx_px_s: f64,
    /// Vertical image velocity in texture pixels per second (positive: content moves down).
    #[serde(default)]
    pub vy_px_s: f64,
    /// Rotation of the content about the view centre, degrees per second.
    #[serde(default)]
    pub rotation_deg_s: f64,
    /// Zoom rate: the content is scaled by `s(t) = exp(zoom_per_s * t)` about the view centre.
    #[serde(default)]
    pub zoom_per_s: f64,
    /// The instant the motion starts, nanoseconds: before it the view holds still at its
    /// starting position; from it on, every rate applies to `t - start_ns` (a scene that turns
    /// from static to moving).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub start_ns: u64,
    /// The instant the motion stops, nanoseconds, after `start_ns`: from it on the view holds
    /// still where the motion left it (a scene that starts and stops). None: it never stops.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop_ns: Option<u64>,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// Lighting beyond the texture.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Optional high-dynamic-range gain map, fixed to the view.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gain_map: Option<GainMapSpec>,
}

/// A gain map that multiplies the texture: its max/min ratio over the view is `10^decades`,
/// with geometric mean 1 (gains run from `10^(-decades/2)` to `10^(+decades/2)`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GainMapSpec {
    /// Shape of the map.
    pub kind: GainMapKind,
    /// log10 of the max/min ratio, in (0, 12].
    pub decades: f64,
}

/// Shapes of gain map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum GainMapKind {
    /// log10 gain rises linearly from the left edge (dimmest) to the right edge (brightest).
    Horizontal,
    /// log10 gain falls linearly with distance from the view centre (brightest) to the corners.
    Radial,
}

fn default_width() -> usize {
    DEFAULT_WIDTH
}
fn default_height() -> usize {
    DEFAULT_HEIGHT
}
fn default_light_scale() -> f64 {
    1.0
}
fn default_samples_per_pixel() -> usize {
    DEFAULT_SAMPLES_PER_PIXEL
}
fn default_contrast() -> f64 {
    1.0
}
fn default_texture_min() -> f64 {
    DEFAULT_TEXTURE_MIN
}

/// Enums written as lower-case YAML strings, with an error listing the accepted values.
macro_rules! string_enum {
    ($ty:ident { $($variant:ident => $name:literal),+ $(,)? }) => {
        impl $ty {
            /// Every value, in documentation order.
            pub const ALL: &'static [$ty] = &[$($ty::$variant),+];

            /// The YAML spelling.
            pub fn as_str(self) -> &'static str {
                match self { $($ty::$variant => $name),+ }
            }

            /// The accepted spellings, comma separated (for error messages).
            pub fn expected() -> String {
                Self::ALL.iter().map(|k| k.as_str()).collect::<Vec<_>>().join(", ")
            }
        }

        impl fmt::Display for $ty {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl FromStr for $ty {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                match s {
                    $($name => Ok($ty::$variant),)+
                    _ => Err(format!(
                        "unknown value {:?} (expected one of {})",
                        s,
                        Self::expected()
                    )),
                }
            }
        }

        impl Serialize for $ty {
            fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                serializer.serialize_str(self.as_str())
            }
        }

        impl<'de> Deserialize<'de> for $ty {
            fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
                // Parsing inside the visitor (not after it) lets serde_yaml attach the
                // field's own path ("texture.kind") to the error.
                struct Visitor;
                impl serde::de::Visitor<'_> for Visitor {
                    type Value = $ty;
                    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                        write!(f, "one of {}", $ty::expected())
                    }
                    fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<$ty, E> {
                        s.parse().map_err(E::custom)
                    }
                }
                deserializer.deserialize_str(Visitor)
            }
        }
    };
}

string_enum!(TextureKind {
    Noise => "noise",
    Shapes => "shapes",
    Grating => "grating",
    Strokes => "strokes",
    Checkerboard => "checkerboard",
    Png => "png",
});

string_enum!(GainMapKind {
    Horizontal => "horizontal",
    Radial => "radial",
});

/// Builds the "invalid value" error for `field`.
fn invalid(
    origin: &str,
    field: &str,
    value: impl fmt::Display,
    reason: impl Into<String>,
) -> SceneError {
    SceneError::Invalid {
        origin: origin.to_owned(),
        field: field.to_owned(),
        value: value.to_string(),
        reason: reason.into(),
    }
}

impl TextureSpec {
    /// A texture of `kind` with every parameter at its default.
    pub fn new(kind: TextureKind) -> TextureSpec {
        TextureSpec {
            kind,
            size: None,
            contrast: default_contrast(),
            min: default_texture_min(),
            beta: None,
            count: None,
            period_px: None,
            angle_deg: None,
            square_px: None,
            path: None,
        }
    }

    /// Canvas side of a procedural texture (the default when unset).
    pub fn size_or_default(&self) -> usize {
        self.size.unwrap_or(DEFAULT_TEXTURE_SIZE)
    }

    fn validate(&self, origin: &str) -> Result<(), SceneError> {
        let kind = self.kind;
        // Parameters that belong to another kind are an error, not silently ignored.
        let params: [(&str, bool, &[TextureKind]); 7] = [
            (
                "texture.size",
                self.size.is_some(),
                &[
                    TextureKind::Noise,
                    TextureKind::Shapes,
                    TextureKind::Grating,
                    TextureKind::Strokes,
                    TextureKind::Checkerboard,
                ],
            ),
            ("texture.beta", self.beta.is_some(), &[TextureKind::Noise]),
            (
                "texture.count",
                self.count.is_some(),
                &[TextureKind::Shapes],
            ),
            (
                "texture.period_px",
                self.period_px.is_some(),
                &[TextureKind::Grating],
            ),
            (
                "texture.angle_deg",
                self.angle_deg.is_some(),
                &[TextureKind::Grating],
            ),
            (
                "texture.square_px",
                self.square_px.is_some(),
                &[TextureKind::Checkerboard],
            ),
            ("texture.path", self.path.is_some(), &[TextureKind::Png]),
        ];
        for (field, present, kinds) in params {
            if present && !kinds.contains(&kind) {
                let used_by = kinds
                    .iter()
                    .map(|k| k.as_str())
                    .collect::<Vec<_>>()
                    .join(", ");
                return Err(SceneError::Unused {
                    origin: origin.to_owned(),
                    field: field.to_owned(),
                    kind: kind.as_str().to_owned(),
                    used_by,
                });
            }
        }
        if let Some(size) = self.size
            && !(MIN_TEXTURE_SIZE..=MAX_TEXTURE_SIZE).contains(&size)
        {
            return Err(invalid(
                origin,
                "texture.size",
                size,
                format!("must be in {MIN_TEXTURE_SIZE}..={MAX_TEXTURE_SIZE}"),
            ));
        }
        if !self.contrast.is_finite() {
            return Err(invalid(
                origin,
                "texture.contrast",
                self.contrast,
                "must be finite",
            ));
        }
        if !(self.min.is_finite() && self.min > 0.0 && self.min < 1.0) {
            return Err(invalid(
                origin,
                "texture.min",
                self.min,
                "must be > 0 and < 1",
            ));
        }
        if let Some(beta) = self.beta
            && !(beta.is_finite() && (0.0..=MAX_NOISE_BETA).contains(&beta))
        {
            return Err(invalid(
                origin,
                "texture.beta",
                beta,
                format!("must be in [0, {MAX_NOISE_BETA}]"),
            ));
        }
        if let Some(count) = self.count
            && count > MAX_SHAPE_COUNT
        {
            return Err(invalid(
                origin,
                "texture.count",
                count,
                format!("must be at most {MAX_SHAPE_COUNT}"),
            ));
        }
        let size = self.size_or_default() as f64;
        if let Some(period) = self.period_px
            && !(period.is_finite() && period >= 2.0 && period <= size)
        {
            return Err(invalid(
                origin,
                "texture.period_px",
                period,
                format!("must be >= 2 and <= texture.size ({size})"),
            ));
        }
        if let Some(angle) = self.angle_deg
            && !angle.is_finite()
        {
            return Err(invalid(
                origin,
                "texture.angle_deg",
                angle,
                "must be finite",
            ));
        }
        if let Some(square) = self.square_px
            && !(square.is_finite() && square >= 1.0 && square <= size / 2.0)
        {
            return Err(invalid(
                origin,
                "texture.square_px",
                square,
                format!("must be >= 1 and <= texture.size / 2 ({})", size / 2.0),
            ));
        }
        if kind == TextureKind::Png {
            match &self.path {
                None => {
                    return Err(SceneError::Missing {
                        origin: origin.to_owned(),
                        field: "texture.path".to_owned(),
                        reason: "required when texture.kind is png".to_owned(),
                    });
                }
                Some(p) if p.trim().is_empty() => {
                    return Err(invalid(origin, "texture.path", "\"\"", "must not be empty"));
                }
                Some(_) => {}
            }
        }
        Ok(())
    }
}

impl MotionSpec {
    /// The motion's own time at `t_ns`, seconds: 0 until `start_ns`, then `t - start_ns`, held
    /// from `stop_ns` on (saturating: any `t_ns` is defined).
    pub fn elapsed_s(&self, t_ns: i64) -> f64 {
        let start = i64::try_from(self.start_ns).unwrap_or(i64::MAX);
        let stop = self
            .stop_ns
            .map_or(i64::MAX, |s| i64::try_from(s).unwrap_or(i64::MAX))
            .max(start);
        t_ns.clamp(start, stop).saturating_sub(start) as f64 / NS_PER_S
    }

    fn validate(&self, origin: &str) -> Result<(), SceneError> {
        for (field, value) in [
            ("motion.vx_px_s", self.vx_px_s),
            ("motion.vy_px_s", self.vy_px_s),
            ("motion.rotation_deg_s", self.rotation_deg_s),
            ("motion.zoom_per_s", self.zoom_per_s),
        ] {
            if !value.is_finite() {
                return Err(invalid(origin, field, value, "must be finite"));
            }
        }
        if let Some(stop) = self.stop_ns
            && stop <= self.start_ns
        {
            return Err(invalid(
                origin,
                "motion.stop_ns",
                stop,
                "must be after motion.start_ns",
            ));
        }
        Ok(())
    }
}

impl SceneSpec {
    /// A scene with every field at its default and the given texture.
    pub fn new(texture: TextureSpec) -> SceneSpec {
        SceneSpec {
            width: DEFAULT_WIDTH,
            height: DEFAULT_HEIGHT,
            duration_ms: None,
            duration_ns: None,
            seed: 0,
            light_scale: default_light_scale(),
            samples_per_pixel: DEFAULT_SAMPLES_PER_PIXEL,
            texture,
            motion: MotionSpec::default(),
            light: None,
        }
    }

    /// The gain map, if the scene has one.
    pub fn gain_map(&self) -> Option<&GainMapSpec> {
        self.light.as_ref().and_then(|l| l.gain_map.as_ref())
    }

    /// Checks every range and combination; `origin` names the source in the error.
    /// Returns the duration in nanoseconds.
    pub fn validate(&self, origin: &str) -> Result<i64, SceneError> {
        for (field, value) in [("width", self.width), ("height", self.height)] {
            if !(1..=MAX_VIEW_SIDE).contains(&value) {
                return Err(invalid(
                    origin,
                    field,
                    value,
                    format!("must be in 1..={MAX_VIEW_SIDE}"),
                ));
            }
        }
        let duration_ns = match (self.duration_ms, self.duration_ns) {
            (Some(ms), Some(ns)) => {
                return Err(SceneError::Conflict {
                    origin: origin.to_owned(),
                    fields: format!("duration_ms ({ms}) and duration_ns ({ns})"),
                    reason: "give at most one of them".to_owned(),
                });
            }
            (Some(ms), None) => ms
                .checked_mul(1_000_000)
                .and_then(|ns| i64::try_from(ns).ok())
                .filter(|&ns| ns > 0)
                .ok_or_else(|| {
                    invalid(
                        origin,
                        "duration_ms",
                        ms,
                        "must be > 0 and fit in i64 nanoseconds",
                    )
                })?,
            (None, Some(ns)) => i64::try_from(ns)
                .ok()
                .filter(|&ns| ns > 0)
                .ok_or_else(|| invalid(origin, "duration_ns", ns, "must be > 0 and fit in i64"))?,
            (None, None) => (DEFAULT_DURATION_MS * 1_000_000) as i64,
        };
        if !(self.light_scale.is_finite() && self.light_scale > 0.0) {
            return Err(invalid(
                origin,
                "light_scale",
                self.light_scale,
                "must be finite and > 0",
            ));
        }
        if !(1..=MAX_SAMPLES_PER_PIXEL).contains(&self.samples_per_pixel) {
            return Err(invalid(
                origin,
                "samples_per_pixel",
                self.samples_per_pixel,
                format!("must be in 1..={MAX_SAMPLES_PER_PIXEL}"),
            ));
        }
        self.texture.validate(origin)?;
        self.motion.validate(origin)?;
        if let Some(gain) = self.gain_map()
            && !(gain.decades.is_finite() && gain.decades > 0.0 && gain.decades <= MAX_GAIN_DECADES)
        {
            return Err(invalid(
                origin,
                "light.gain_map.decades",
                gain.decades,
                format!("must be > 0 and <= {MAX_GAIN_DECADES}"),
            ));
        }
        Ok(duration_ns)
    }
}
