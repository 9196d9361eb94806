//! The scene both camera simulators draw from: luminance `I(x, y, t)` of a textured plane moving
//! under a fixed view, at any instant (integer nanoseconds), with sub-pixel supersampling.
//!
//! A scene is a YAML file: a texture (procedural generator or PNG), constant-rate motion, a light
//! scale the cameras apply, an optional high-dynamic-range gain map, the view size, the duration
//! and a seed. Rendering is deterministic for a given seed. A scene can also be a clip of video
//! frames ([`Scene::from_clip`], [`Clip`]): the light linear in time between them.
//!
//! ```yaml
//! width: 400            # view width in scene pixels (default 400)
//! height: 250           # view height in scene pixels (default 250)
//! duration_ms: 50       # default 50; or duration_ns (at most one of the two)
//! seed: 7               # default 0; drives every random choice of the texture
//! light_scale: 1.0      # default 1.0, finite and > 0; applied by the cameras, not by render
//! samples_per_pixel: 2  # supersampling grid per axis, 1..=8 (1 = pixel centre), default 2
//! texture:
//!   kind: noise         # noise | shapes | grating | strokes | checkerboard | png
//!   beta: 2.0           # noise: power spectrum ~ 1/f^beta (default 2)
//!   size: 512           # canvas side of procedural textures (default 512)
//!   contrast: 1.0       # t' = 0.5 + contrast * (t - 0.5) (default 1)
//!   min: 0.05           # floor: values clamped to [min, 1] (default 0.02)
//! motion:               # constant rates, all default 0
//!   vx_px_s: 200.0      # content moves right at 200 texture px/s
//!   vy_px_s: 0.0
//!   rotation_deg_s: 0.0 # about the view centre
//!   zoom_per_s: 0.0     # content scaled by s(t) = exp(zoom_per_s * t) about the view centre
//!   start_ns: 0         # the view holds still until then; the rates apply to t - start_ns
//!   stop_ns: 40000000   # optional: the view holds still again from then on
//! light:
//!   gain_map:           # optional
//!     kind: horizontal  # horizontal (log-linear ramp, left dim) | radial (bright centre)
//!     decades: 6.0      # max/min gain over the view = 10^decades, geometric mean 1
//! ```
//!
//! Texture parameters: `noise` takes `beta`; `shapes` takes `count` (default 40);
//! `grating` takes `period_px` (default 32) and `angle_deg` (default 0); `checkerboard` takes
//! `square_px` (default 32); `strokes` takes none; `png` takes `path` (8- or 16-bit grey, grey+alpha,
//! RGB or RGBA; luminance with Rec. 709 weights on the stored values, alpha ignored) and no `size`.
//! A parameter given for a kind that does not use it is an error.
//!
//! Tiling: procedural textures are periodic by construction (noise by spectral synthesis, shapes
//! and strokes drawn with wrap-around, the grating's frequency and the checkerboard's square size
//! snapped to whole periods per canvas), so motion never runs out and no seam shows. PNG images
//! are mirror-tiled (period twice the image in each direction). One texture pixel is one scene
//! pixel at zoom 1, and the view's top-left corner shows the texture's top-left corner at `t = 0`.
//!
//! Geometry: view point `p` at time `t` shows texture point `R(-theta(t)) (p - c) / s(t) + c - v t`
//! where `c` is the view centre, `theta(t) = rotation_deg_s * t`, `s(t) = exp(zoom_per_s * t)`,
//! and `t` counts from `motion.start_ns` (0 before it), held at its value at `motion.stop_ns`
//! from then on when a stop is given.
//! The gain map is fixed to the view (a static lighting gradient the content moves under).
//!
//! ```
//! use neuspike_scene::Scene;
//! let scene = Scene::from_yaml_str(
//!     "texture: { kind: checkerboard, size: 64, square_px: 8 }\nmotion: { vx_px_s: 1000.0 }",
//!     "doc",
//!     None,
//! )
//! .unwrap();
//! // The view (400 x 250 scene pixels) mapped onto any grid, here 25 x 40.
//! let a = scene.render(0, 25, 40);
//! assert_eq!(a.dim(), (25, 40));
//! assert!(a.iter().all(|&v| (0.02..=1.0).contains(&v)));
//! // 1 ms at 1000 px/s moves the content 1 scene pixel to the right.
//! let b = scene.render(1_000_000, 250, 400);
//! let c = scene.render(0, 250, 400);
//! assert!((b[[100, 201]] - c[[100, 200]]).abs() < 1e-5);
//! ```
#![deny(missing_docs)]

mod builtin;
mod clip;
mod error;
mod fft;
mod gain;
mod render;
pub mod shift;
mod spec;
mod texture;

use std::path::Path;
use std::sync::Arc;

use ndarray::{Array2, ArrayViewMut2};

pub use clip::{Clip, MAX_CLIP_FRAMES};
pub use error::SceneError;
pub use spec::{
    GainMapKind, GainMapSpec, LightSpec, MotionSpec, SceneSpec, TextureKind, TextureSpec,
};
pub use texture::Texture;

use gain::GainMap;

/// A loaded scene: validated spec, generated texture, gain map. Cheap to clone (the texture is
/// shared).
#[derive(Clone, Debug)]
pub struct Scene {
    spec: SceneSpec,
    duration_ns: i64,
    texture: Arc<Texture>,
    texture_min: f32,
    gain: Option<GainMap>,
    /// The frames of a clip scene ([`Scene::from_clip`]), which replace texture and motion.
    clip: Option<Arc<Clip>>,
}

impl Scene {
    /// Builds a scene from a spec; `base_dir` resolves a relative PNG path.
    pub fn from_spec(spec: SceneSpec, base_dir: Option<&Path>) -> Result<Scene, SceneError> {
        Scene::from_spec_at(spec, base_dir, "spec")
    }

    fn from_spec_at(
        spec: SceneSpec,
        base_dir: Option<&Path>,
        origin: &str,
    ) -> Result<Scene, SceneError> {
        let duration_ns = spec.validate(origin)?;
        let texture = Texture::from_spec(&spec.texture, spec.seed, base_dir, origin)?;
        let gain = spec
            .gain_map()
            .map(|g| GainMap::new(g, spec.width, spec.height));
        Ok(Scene {
            texture_min: spec.texture.min as f32,
            duration_ns,
            texture: Arc::new(texture),
            gain,
            spec,
            clip: None,
        })
    }

    /// A scene of video frames: the view is the clip's frames (`width x height` their sides,
    /// one sample a pixel), the light linear in time between them, held before the first and
    /// after the last ([`Clip`]); the duration runs to the last frame (at least 1 ns). There
    /// is no texture motion or gain map: [`Scene::texture`] is the first frame, and
    /// [`Scene::content_shift`] and [`Scene::content_path`] are 0.
    ///
    /// # Errors
    /// A `light_scale` that is not finite and above 0.
    pub fn from_clip(clip: Clip, light_scale: f64) -> Result<Scene, SceneError> {
        if !(light_scale.is_finite() && light_scale > 0.0) {
            return Err(SceneError::Invalid {
                origin: "clip".to_owned(),
                field: "light_scale".to_owned(),
                value: light_scale.to_string(),
                reason: "must be finite and > 0".to_owned(),
            });
        }
        let mut spec = SceneSpec::new(TextureSpec::new(TextureKind::Png));
        spec.width = clip.width();
        spec.height = clip.height();
        spec.light_scale = light_scale;
        spec.samples_per_pixel = 1;
        spec.texture.min = 0.0;
        spec.duration_ns = Some(clip.last_ns().max(1) as u64);
        let first = clip.frames().index_axis(ndarray::Axis(0), 0);
        let texture =
            Texture::from_texels(clip.width(), clip.height(), first.iter().copied().collect());
        Ok(Scene {
            duration_ns: clip.last_ns().max(1),
            texture: Arc::new(texture),
            texture_min: 0.0,
            gain: None,
            spec,
            clip: Some(Arc::new(clip)),
        })
    }

    /// The frames, for a scene made by [`Scene::from_clip`].
    pub fn clip(&self) -> Option<&Clip> {
        self.clip.as_deref()
    }

    /// The longest time over which the scene's light is linear in time, where it has one: a
    /// clip's time between frames. Cameras step at most this far between renders.
    pub fn linear_for_ns(&self) -> Option<i64> {
        self.clip.as_ref().map(|c| c.dt_ns())
    }

    /// Parses and builds a scene from YAML; `origin` names the source in errors, `base_dir`
    /// resolves a relative PNG path.
    pub fn from_yaml_str(
        yaml: &str,
        origin: &str,
        base_dir: Option<&Path>,
    ) -> Result<Scene, SceneError> {
        let spec: SceneSpec = serde_yaml::from_str(yaml).map_err(|e| SceneError::Parse {
            origin: origin.to_owned(),
            message: field_prefixed(e.to_string()),
        })?;
        Scene::from_spec_at(spec, base_dir, origin)
    }

    /// Reads a scene file; a relative PNG path is resolved against the file's folder.
    pub fn from_path(path: &Path) -> Result<Scene, SceneError> {
        let origin = path.display().to_string();
        let yaml = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
            origin: origin.clone(),
            source,
        })?;
        Scene::from_yaml_str(&yaml, &origin, path.parent())
    }

    /// One of the scenes shipped in `graphs/scenes/` (embedded at build time):
    /// "bright-static", "bright-slow", "bright-fast", "dark-slow", "hdr-pan".
    pub fn builtin(name: &str) -> Result<Scene, SceneError> {
        let yaml = builtin::yaml(name).ok_or_else(|| SceneError::UnknownBuiltin {
            name: name.to_owned(),
            expected: builtin::NAMES.join(", "),
        })?;
        Scene::from_yaml_str(yaml, &format!("graphs/scenes/{name}.yml (builtin)"), None)
    }

    /// The names [`Scene::builtin`] accepts.
    pub fn builtin_names() -> &'static [&'static str] {
        builtin::NAMES
    }

    /// A builtin scene if `name_or_path` names one, else the scene file at that path.
    pub fn load(name_or_path: &str) -> Result<Scene, SceneError> {
        if builtin::yaml(name_or_path).is_some() {
            Scene::builtin(name_or_path)
        } else {
            Scene::from_path(Path::new(name_or_path))
        }
    }

    /// The spec as given (defaults filled in by serde, nothing else changed).
    pub fn spec(&self) -> &SceneSpec {
        &self.spec
    }
    /// View width in scene pixels.
    pub fn width(&self) -> usize {
        self.spec.width
    }
    /// View height in scene pixels.
    pub fn height(&self) -> usize {
        self.spec.height
    }
    /// Duration in nanoseconds (> 0).
    pub fn duration_ns(&self) -> i64 {
        self.duration_ns
    }
    /// Light level the cameras multiply the luminance by (finite, > 0).
    pub fn light_scale(&self) -> f64 {
        self.spec.light_scale
    }
    /// The seed of the procedural texture.
    pub fn seed(&self) -> u64 {
        self.spec.seed
    }
    /// The texture canvas (one period).
    pub fn texture(&self) -> &Texture {
        &self.texture
    }

    /// Luminance `I(x, y, t) >= 0` at instant `t_ns`, written into `dst` (row-major
    /// `[rows, cols]`, any shape and strides). The view (`width x height` scene pixels) is
    /// mapped onto `dst`'s grid, so cameras of different resolutions see the same view.
    /// Texture values lie in `[min, 1]`; a gain map multiplies them (only then can `I` exceed 1).
    /// `light_scale` is not applied. Never NaN or infinite.
    pub fn render_into(&self, t_ns: i64, dst: ArrayViewMut2<'_, f32>) {
        let (rows, cols) = dst.dim();
        if let Some(clip) = &self.clip {
            let whole = render::Region::whole(rows, cols);
            return clip::render_region(clip, self.spec.samples_per_pixel, t_ns, whole, dst);
        }
        render::render_fast(self, t_ns, dst, render::worth_parallel(self, rows, cols));
    }

    /// Luminance as another camera sees the view: destination pixel `(c, r)`'s sub-samples at
    /// `(c + ox, r + oy)` (its own pixel coordinates) are taken by `map` to the view's
    /// coordinates (scene pixels) and sampled there as [`Scene::render_into`] samples them; a
    /// sub-sample `map` sends nowhere (`None`) sees black. Scalar, in `f64`, rows in parallel.
    /// Never NaN or infinite.
    pub fn render_mapped_into(
        &self,
        t_ns: i64,
        map: &(dyn Fn(f64, f64) -> Option<(f64, f64)> + Sync),
        dst: ArrayViewMut2<'_, f32>,
    ) {
        match &self.clip {
            Some(clip) => clip::render_mapped(clip, self.spec.samples_per_pixel, t_ns, map, dst),
            None => render::render_mapped(self, t_ns, map, dst),
        }
    }

    /// Part of what a `sensor_rows x sensor_cols` camera sees, as [`Scene::render_into`] renders
    /// it: destination pixel `(r, c)` is sensor pixel `(row0 + r, col0 + c)`, which may lie
    /// beyond the sensor's edges (the scene goes on past the view: a margin for shifting the
    /// image later) and between its pixels (a fractional origin samples the view that much
    /// further on). A non-finite origin counts as 0.
    pub fn render_region_into(
        &self,
        t_ns: i64,
        sensor: [usize; 2],
        origin: [f64; 2],
        dst: ArrayViewMut2<'_, f32>,
    ) {
        let (rows, cols) = dst.dim();
        let region = render::Region::at(sensor, origin);
        if let Some(clip) = &self.clip {
            return clip::render_region(clip, self.spec.samples_per_pixel, t_ns, region, dst);
        }
        let parallel = render::worth_parallel(self, rows, cols);
        render::render_fast_region(self, t_ns, region, dst, parallel);
    }

    /// [`Scene::render_into`] into a new `rows x cols` array.
    pub fn render(&self, t_ns: i64, rows: usize, cols: usize) -> Array2<f32> {
        let mut out = Array2::zeros((rows, cols));
        self.render_into(t_ns, out.view_mut());
        out
    }

    /// How far the content at the view's centre moves from `t_from_ns` to `t_to_ns`, in scene
    /// pixels `(dx, dy)`: the translation `s(t_to) R(theta(t_to)) v (t_to - t_from)` (rotation and
    /// zoom turn about the centre, so they move it not). Elsewhere in the view a turning or
    /// zooming scene moves by this plus its rotation and scale about the centre. Times before the
    /// motion starts count as its start, times after it stops as its stop; finite for any
    /// instants.
    pub fn content_shift(&self, t_from_ns: i64, t_to_ns: i64) -> (f64, f64) {
        let m = &self.spec.motion;
        let (t1, t2) = (m.elapsed_s(t_from_ns), m.elapsed_s(t_to_ns));
        let theta = (m.rotation_deg_s * t2).rem_euclid(360.0).to_radians();
        let (sin, cos) = theta.sin_cos();
        let s = (m.zoom_per_s * t2)
            .clamp(-render::MAX_LOG_ZOOM, render::MAX_LOG_ZOOM)
            .exp();
        let (dx, dy) = (m.vx_px_s * (t2 - t1), m.vy_px_s * (t2 - t1));
        let shift = (s * (cos * dx - sin * dy), s * (sin * dx + cos * dy));
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        (finite(shift.0), finite(shift.1))
    }

    /// Where the content at the view's centre has moved since the motion started, at `t_ns`, in
    /// scene pixels `(dx, dy)`: the integral of the velocity [`Scene::content_shift`] takes at
    /// its end, `s(t) R(theta(t)) v`, in closed form (the log zoom held at its clamp once it
    /// reaches it). The difference between two instants is how far the centre's content moves
    /// between them, to first order in the turn and zoom between; unlike `content_shift`'s,
    /// such differences add up along a path. Times before the motion starts count as its start,
    /// times after it stops as its stop; finite for any instant.
    pub fn content_path(&self, t_ns: i64) -> (f64, f64) {
        let m = &self.spec.motion;
        let t = m.elapsed_s(t_ns);
        let omega = m.rotation_deg_s.to_radians();
        let z = m.zoom_per_s;
        // Until the log zoom reaches its clamp (`z t = +-MAX_LOG_ZOOM`), then at the clamp.
        let t_clamp = if z == 0.0 {
            f64::INFINITY
        } else {
            render::MAX_LOG_ZOOM / z.abs()
        };
        let t1 = t.min(t_clamp);
        let mut path = exp_integral(z, omega, t1);
        if t > t_clamp {
            let held = (z.signum() * render::MAX_LOG_ZOOM).exp();
            let (sin, cos) = (omega * t_clamp).sin_cos();
            let (re, im) = exp_integral(0.0, omega, t - t_clamp);
            path.0 += held * (cos * re - sin * im);
            path.1 += held * (sin * re + cos * im);
        }
        let (vx, vy) = (m.vx_px_s, m.vy_px_s);
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        (
            finite(path.0 * vx - path.1 * vy),
            finite(path.1 * vx + path.0 * vy),
        )
    }

    /// Whether the image never changes: no translation, rotation or zoom (nothing else in a scene
    /// depends on time).
    pub fn is_static(&self) -> bool {
        if let Some(clip) = &self.clip {
            return clip.len() == 1;
        }
        let m = &self.spec.motion;
        m.vx_px_s == 0.0 && m.vy_px_s == 0.0 && m.rotation_deg_s == 0.0 && m.zoom_per_s == 0.0
    }

    /// Upper bound of the speed of any image point over the scene's duration, in scene pixels
    /// per second: `|v| * max s(t) + (|omega| + |zoom_per_s|) * r_corner`, where `r_corner` is
    /// the distance from the view centre to a corner and `omega` is in rad/s.
    pub fn max_speed_px_per_s(&self) -> f64 {
        let m = &self.spec.motion;
        let duration_s = self.duration_ns as f64 / spec::NS_PER_S;
        let max_log_scale = (m.zoom_per_s * duration_s).clamp(0.0, render::MAX_LOG_ZOOM);
        let corner = (self.width() as f64 / 2.0).hypot(self.height() as f64 / 2.0);
        let translation = m.vx_px_s.hypot(m.vy_px_s) * max_log_scale.exp();
        let rotation = m.rotation_deg_s.to_radians().abs() * corner;
        let zoom = m.zoom_per_s.abs() * corner;
        translation + rotation + zoom
    }
}

/// `(e^{lambda t} - 1) / lambda` for `lambda = a + i b`, as `(re, im)`: the integral of
/// `e^{lambda u}` over `[0, t]`. Where `|lambda t|` is tiny the quotient would cancel, and its
/// series `t (1 + lambda t / 2 + (lambda t)^2 / 6)` is used; `lambda = 0` gives `t`.
fn exp_integral(a: f64, b: f64, t: f64) -> (f64, f64) {
    let (x, y) = (a * t, b * t);
    if x.hypot(y) < 1e-4 {
        // t (1 + w / 2 + w^2 / 6), w = x + i y.
        let (w2r, w2i) = (x * x - y * y, 2.0 * x * y);
        return (t * (1.0 + x / 2.0 + w2r / 6.0), t * (y / 2.0 + w2i / 6.0));
    }
    let e = x.exp();
    let (sin, cos) = y.sin_cos();
    let (nr, ni) = (e * cos - 1.0, e * sin);
    // (nr + i ni) / (a + i b)
    let d = a * a + b * b;
    ((nr * a + ni * b) / d, (ni * a - nr * b) / d)
}

/// serde_yaml starts a message with the field path (`texture.kind: ...`) when there is one;
/// spell it `field texture.kind: ...` like the validation errors.
fn field_prefixed(message: String) -> String {
    let is_path_char = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '[' | ']');
    match message.split_once(": ") {
        Some((path, _)) if !path.is_empty() && path.chars().all(is_path_char) => {
            format!("field {message}")
        }
        _ => message,
    }
}

/// The scalar oracle of [`Scene::render_into`]: every sub-sample from scratch, in f64. Slow;
/// for tests and benchmarks.
#[doc(hidden)]
pub fn render_reference(scene: &Scene, t_ns: i64, dst: ArrayViewMut2<'_, f32>) {
    if scene.clip.is_some() {
        // A clip's render is scalar already: its own reference.
        return scene.render_into(t_ns, dst);
    }
    render::render_reference(scene, t_ns, dst);
}

/// The scalar oracle of [`Scene::render_region_into`].
pub fn render_reference_region(
    scene: &Scene,
    t_ns: i64,
    sensor: [usize; 2],
    origin: [f64; 2],
    dst: ArrayViewMut2<'_, f32>,
) {
    if scene.clip.is_some() {
        return scene.render_region_into(t_ns, sensor, origin, dst);
    }
    let region = render::Region::at(sensor, origin);
    render::render_reference_region(scene, t_ns, region, dst);
}

/// [`Scene::render_into`] with the thread choice forced (tests of the parallel path).
#[doc(hidden)]
pub fn render_fast_with(scene: &Scene, t_ns: i64, dst: ArrayViewMut2<'_, f32>, parallel: bool) {
    if scene.clip.is_some() {
        return scene.render_into(t_ns, dst);
    }
    render::render_fast(scene, t_ns, dst, parallel);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send_sync<T: Send + Sync + Clone + std::fmt::Debug>() {}

    #[test]
    fn scene_is_send_sync_clone_debug() {
        assert_send_sync::<Scene>();
    }
}
