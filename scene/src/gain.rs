//! High-dynamic-range gain maps. A gain map is fixed to the view (scene coordinates), not to the
//! texture: the content moves under a static lighting gradient, like a pan past a bright window.

use std::f64::consts::LN_10;

use crate::spec::{GainMapKind, GainMapSpec};

/// A gain map over a `width x height` view: `log10 gain` spans `[-decades/2, +decades/2]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GainMap {
    kind: GainMapKind,
    decades: f64,
    width: f64,
    height: f64,
    /// Distance from the view centre to a corner.
    corner: f64,
}

impl GainMap {
    pub fn new(spec: &GainMapSpec, width: usize, height: usize) -> GainMap {
        let (width, height) = (width as f64, height as f64);
        GainMap {
            kind: spec.kind,
            decades: spec.decades,
            width,
            height,
            corner: (width / 2.0).hypot(height / 2.0),
        }
    }

    /// Whether the gain depends on `x` only.
    pub fn is_horizontal(&self) -> bool {
        self.kind == GainMapKind::Horizontal
    }

    /// Gain at scene point (`x`, `y`). Horizontal: `10^(decades * (x / width - 1/2))`;
    /// radial: `10^(decades * (1/2 - r / r_corner))` with `r` the distance to the view centre.
    /// Beyond the view (a margin rendered around it) the gain is the nearest edge's: the map
    /// describes the view's light and is not extrapolated.
    pub fn gain_at(&self, x: f64, y: f64) -> f64 {
        let (x, y) = (x.clamp(0.0, self.width), y.clamp(0.0, self.height));
        let log10_gain = match self.kind {
            GainMapKind::Horizontal => self.decades * (x / self.width - 0.5),
            GainMapKind::Radial => {
                let r = (x - self.width / 2.0).hypot(y - self.height / 2.0);
                self.decades * (0.5 - r / self.corner)
            }
        };
        (log10_gain * LN_10).exp()
    }
}
