//! Geometry between the two cameras of a hybrid rig (a spike camera and a DVS behind a beam
//! splitter): the homography that takes a pixel of one sensor to the other's pixel grid.
//!
//! Pixel coordinates: `x` to the right, `y` down, pixel `(c, r)` covering `[c, c + 1) x
//! [r, r + 1)`, so its centre is `(c + 0.5, r + 0.5)`.
#![deny(missing_docs)]

use std::fmt;

/// A projective map of the plane, `(x, y) -> ((h11 x + h12 y + h13) / w, (h21 x + h22 y + h23) /
/// w)` with `w = h31 x + h32 y + h33`, stored row-major and scaled so that `h33 = 1` when it is
/// not 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography {
    h: [f64; 9],
}

/// A homography that cannot be used; the message names the value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum HomographyError {
    /// Not nine comma-separated numbers.
    #[error("homography `{text}`: {why}")]
    Parse {
        /// The text given.
        text: String,
        /// What is wrong.
        why: String,
    },
    /// A coefficient is NaN or infinite.
    #[error("homography: coefficient h{index} = {value} is not finite")]
    NotFinite {
        /// Row and column, 1-based (`11` .. `33`).
        index: u8,
        /// The value.
        value: f64,
    },
    /// The matrix has no inverse (its determinant is 0 to within rounding).
    #[error("homography: singular (determinant {det:e})")]
    Singular {
        /// The determinant, after scaling to `h33 = 1`.
        det: f64,
    },
}

/// A determinant this small, relative to the matrix's scale, counts as singular.
const SINGULAR: f64 = 1e-12;

/// The image of a point at `w` this close to 0 is at infinity: [`Homography::apply`] gives `None`.
const MIN_W: f64 = 1e-12;

impl Homography {
    /// The identity.
    pub const IDENTITY: Homography = Homography {
        h: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    };

    /// From nine row-major coefficients, checked: finite and invertible; scaled to `h33 = 1`
    /// when it is not 0.
    ///
    /// # Errors
    /// A coefficient not finite, or the matrix singular.
    pub fn new(h: [f64; 9]) -> Result<Homography, HomographyError> {
        for (i, &v) in h.iter().enumerate() {
            if !v.is_finite() {
                return Err(HomographyError::NotFinite {
                    index: (i / 3 + 1) as u8 * 10 + (i % 3 + 1) as u8,
                    value: v,
                });
            }
        }
        let mut h = h;
        if h[8] != 0.0 {
            let s = h[8];
            for v in &mut h {
                *v /= s;
            }
        }
        let m = Homography { h };
        let scale = h.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let det = m.determinant();
        // NaN cannot occur (the coefficients are finite); 0 and tiny are singular.
        if det.abs() <= SINGULAR * scale.powi(3) {
            return Err(HomographyError::Singular { det });
        }
        Ok(m)
    }

    /// `(x, y) -> (sx x + tx, sy y + ty)`.
    ///
    /// # Errors
    /// A scale of 0 or a value not finite.
    pub fn scale_translate(
        sx: f64,
        sy: f64,
        tx: f64,
        ty: f64,
    ) -> Result<Homography, HomographyError> {
        Homography::new([sx, 0.0, tx, 0.0, sy, ty, 0.0, 0.0, 1.0])
    }

    /// Parses nine comma-separated numbers, row-major (`h11,h12,h13,h21,...,h33`), spaces
    /// allowed.
    ///
    /// # Errors
    /// Not nine numbers, or [`Homography::new`]'s.
    pub fn parse(text: &str) -> Result<Homography, HomographyError> {
        let bad = |why: String| HomographyError::Parse {
            text: text.to_string(),
            why,
        };
        let parts: Vec<&str> = text.split(',').map(str::trim).collect();
        if parts.len() != 9 {
            return Err(bad(format!(
                "{} values; nine are needed, row-major: h11,h12,h13,h21,h22,h23,h31,h32,h33",
                parts.len()
            )));
        }
        let mut h = [0.0; 9];
        for (v, p) in h.iter_mut().zip(&parts) {
            *v = p
                .parse()
                .map_err(|_| bad(format!("`{p}` is not a number")))?;
        }
        Homography::new(h)
    }

    /// The coefficients, row-major.
    pub fn coefficients(&self) -> [f64; 9] {
        self.h
    }

    fn determinant(&self) -> f64 {
        let h = &self.h;
        h[0] * (h[4] * h[8] - h[5] * h[7]) - h[1] * (h[3] * h[8] - h[5] * h[6])
            + h[2] * (h[3] * h[7] - h[4] * h[6])
    }

    /// The image of `(x, y)`; `None` where the map sends it to infinity or behind the camera
    /// (`w <= 1e-12`).
    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let h = &self.h;
        let w = h[6] * x + h[7] * y + h[8];
        // w is finite for finite inputs; NaN (a NaN input) also gives None.
        if w.is_nan() || w <= MIN_W {
            return None;
        }
        Some((
            (h[0] * x + h[1] * y + h[2]) / w,
            (h[3] * x + h[4] * y + h[5]) / w,
        ))
    }

    /// The inverse map.
    pub fn inverse(&self) -> Homography {
        let h = &self.h;
        let det = self.determinant();
        // The adjugate over the determinant (the determinant is not 0: checked at construction).
        let adj = [
            h[4] * h[8] - h[5] * h[7],
            h[2] * h[7] - h[1] * h[8],
            h[1] * h[5] - h[2] * h[4],
            h[5] * h[6] - h[3] * h[8],
            h[0] * h[8] - h[2] * h[6],
            h[2] * h[3] - h[0] * h[5],
            h[3] * h[7] - h[4] * h[6],
            h[1] * h[6] - h[0] * h[7],
            h[0] * h[4] - h[1] * h[3],
        ];
        let mut inv = adj.map(|v| v / det);
        if inv[8] != 0.0 {
            let s = inv[8];
            for v in &mut inv {
                *v /= s;
            }
        }
        Homography { h: inv }
    }

    /// `self` after `first`: `x -> self(first(x))`.
    pub fn after(&self, first: &Homography) -> Homography {
        let (a, b) = (&self.h, &first.h);
        let mut m = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                m[r * 3 + c] = (0..3).map(|k| a[r * 3 + k] * b[k * 3 + c]).sum();
            }
        }
        if m[8] != 0.0 {
            let s = m[8];
            for v in &mut m {
                *v /= s;
            }
        }
        Homography { h: m }
    }

    /// Where pixel `(c, r)`'s centre lands, as the pixel of the target grid `width x height`
    /// that holds it; `None` outside the grid.
    #[inline]
    pub fn pixel(&self, c: u32, r: u32, width: usize, height: usize) -> Option<(usize, usize)> {
        let (x, y) = self.apply(f64::from(c) + 0.5, f64::from(r) + 0.5)?;
        let (fx, fy) = (x.floor(), y.floor());
        if fx >= 0.0 && fy >= 0.0 && fx < width as f64 && fy < height as f64 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }
}

impl fmt::Display for Homography {
    /// The nine coefficients as [`Homography::parse`] reads them (round trip exact).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let parts: Vec<String> = self.h.iter().map(|v| format!("{v:?}")).collect();
        write!(f, "{}", parts.join(","))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Homography {
        // A DVS 346x260 seeing the spike camera's 400x250 view, slightly rotated and shifted,
        // with a little perspective.
        Homography::new([1.1, 0.02, 5.0, -0.015, 1.05, -8.0, 1e-5, -2e-5, 1.0]).unwrap()
    }

    #[test]
    fn parse_display_round_trip_and_errors_name_the_value() {
        let h = rig();
        assert_eq!(Homography::parse(&h.to_string()).unwrap(), h);
        let e = Homography::parse("1,0,0,0,1,0").unwrap_err().to_string();
        assert!(e.contains("6 values") && e.contains("nine"), "{e}");
        let e = Homography::parse("1,0,0,0,x,0,0,0,1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`x`"), "{e}");
        let e = Homography::parse("1,0,0,0,NaN,0,0,0,1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("h22") && e.contains("NaN"), "{e}");
        let e = Homography::parse("1,2,0,2,4,0,0,0,1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("singular"), "{e}");
        // Scaled to h33 = 1.
        let s = Homography::parse("2,0,0,0,2,0,0,0,2").unwrap();
        assert_eq!(s, Homography::IDENTITY);
    }

    #[test]
    fn pixels_land_inside_or_not_at_all() {
        let h = Homography::scale_translate(400.0 / 346.0, 250.0 / 260.0, 0.0, 0.0).unwrap();
        assert_eq!(h.pixel(0, 0, 400, 250), Some((0, 0)));
        assert_eq!(h.pixel(345, 259, 400, 250), Some((399, 249)));
        let off = Homography::scale_translate(1.0, 1.0, -10.0, 0.0).unwrap();
        assert_eq!(off.pixel(5, 5, 400, 250), None);
        // Behind the camera: w < 0.
        let p = Homography::new([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.01, 0.0, 1.0]).unwrap();
        assert_eq!(p.apply(200.0, 0.0), None);
    }

    proptest::proptest! {
        #[test]
        fn inverse_and_composition_undo_the_map(x in 0.0f64..346.0, y in 0.0f64..260.0) {
            let h = rig();
            let (u, v) = h.apply(x, y).unwrap();
            let (x2, y2) = h.inverse().apply(u, v).unwrap();
            proptest::prop_assert!((x - x2).abs() < 1e-9 && (y - y2).abs() < 1e-9);
            let id = h.inverse().after(&h);
            let (x3, y3) = id.apply(x, y).unwrap();
            proptest::prop_assert!((x - x3).abs() < 1e-9 && (y - y3).abs() < 1e-9);
        }
    }
}
