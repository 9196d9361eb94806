//! Representation tensors and luminance frames.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow::array::{Array, ArrayRef, Float32Array};
use arrow::datatypes::DataType;
use ndarray::{Array2, Array3};

use crate::meta::{self, Meta, MetaExt, Parameter, SchemaError, check_type, int_of};
use crate::{Message, RepresentationKind};

fn floats<'a>(message: &'static str, data: &'a ArrayRef) -> Result<&'a Float32Array, SchemaError> {
    check_type(message, &DataType::Float32, data.data_type())?;
    let a = data
        .as_any()
        .downcast_ref::<Float32Array>()
        .ok_or_else(|| SchemaError::BadType {
            message,
            expected: "Float32".into(),
            found: data.data_type().to_string(),
        })?;
    if a.null_count() != 0 {
        return Err(SchemaError::Inconsistent {
            message,
            what: format!("payload has {} nulls", a.null_count()),
        });
    }
    Ok(a)
}

fn non_finite(message: &'static str, values: &[f32]) -> Result<(), SchemaError> {
    // A pass without early exit (it vectorises); the position only when something is wrong.
    if values.iter().fold(true, |ok, v| ok & v.is_finite()) {
        return Ok(());
    }
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(SchemaError::Inconsistent {
            message,
            what: format!(
                "value {i} is {} (NaN or infinite values never travel)",
                values[i]
            ),
        }),
    }
}

/// The `kind` key of a representation, parsed.
fn kind_of(m: &Meta) -> Result<RepresentationKind, SchemaError> {
    let name = m.string("representation", meta::KIND)?;
    name.parse().map_err(|_| SchemaError::BadKey {
        message: "representation",
        key: meta::KIND,
        expected: "a representation kind",
        found: format!("{name:?} (not one of {})", RepresentationKind::accepted()),
    })
}

/// A representation tensor `[C, H, W]` computed at `t_ref_ns`.
///
/// The kinds the represent node produces are [`RepresentationKind`]s. Numeric parameters travel as
/// `param.<name>` metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct Representation {
    /// What the tensor holds.
    pub kind: RepresentationKind,
    /// The reconstruction instant, nanoseconds.
    pub t_ref_ns: i64,
    /// Sequence number (the aligned window's).
    pub seq: u64,
    /// Numeric parameters (window length, tau, calibration).
    pub params: BTreeMap<String, f64>,
    /// The tensor `[C, H, W]`, finite values.
    pub data: Array3<f32>,
}

impl Message for Representation {
    const TYPE_URN: &'static str = "neuspike/messages/v1/Representation";

    fn data_type() -> DataType {
        DataType::Float32
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        let (c, h, w) = self.data.dim();
        let mut m = Meta::new();
        m.set_string(meta::KIND, self.kind.name());
        m.set_int(meta::CHANNELS, int_of(c));
        m.set_int(meta::HEIGHT, int_of(h));
        m.set_int(meta::WIDTH, int_of(w));
        m.set_int(meta::T_REF_NS, self.t_ref_ns);
        m.set_int(meta::SEQ, self.seq as i64);
        for (k, v) in &self.params {
            m.insert(format!("{}{k}", meta::PARAM_PREFIX), Parameter::Float(*v));
        }
        let values: Vec<f32> = match self.data.as_slice() {
            Some(s) => s.to_vec(),
            None => self.data.iter().copied().collect(),
        };
        (m, Arc::new(Float32Array::from(values)))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        const NAME: &str = "representation";
        let a = floats(NAME, data)?;
        let c = m.size(NAME, meta::CHANNELS)?;
        let h = m.size(NAME, meta::HEIGHT)?;
        let w = m.size(NAME, meta::WIDTH)?;
        let expected = c.saturating_mul(h).saturating_mul(w);
        if a.len() != expected {
            return Err(SchemaError::Inconsistent {
                message: NAME,
                what: format!(
                    "payload has {} values, header says {c}x{h}x{w} = {expected}",
                    a.len()
                ),
            });
        }
        non_finite(NAME, a.values())?;
        let mut params = BTreeMap::new();
        for (k, v) in m {
            if let Some(name) = k.strip_prefix(meta::PARAM_PREFIX) {
                let value = match v {
                    Parameter::Float(f) => *f,
                    Parameter::Integer(i) => *i as f64,
                    other => {
                        return Err(SchemaError::Inconsistent {
                            message: NAME,
                            what: format!("parameter `{k}` is {other:?}, expected a number"),
                        });
                    }
                };
                params.insert(name.to_string(), value);
            }
        }
        let data = Array3::from_shape_vec((c, h, w), a.values().to_vec()).map_err(|e| {
            SchemaError::Inconsistent {
                message: NAME,
                what: e.to_string(),
            }
        })?;
        Ok(Representation {
            kind: kind_of(m)?,
            t_ref_ns: m.int(NAME, meta::T_REF_NS)?,
            seq: m.uint(NAME, meta::SEQ)?,
            params,
            data,
        })
    }
}

/// Whether a frame is a reconstruction or the simulator's ground truth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// Produced by a reconstruction method.
    Reconstruction,
    /// The scene's true luminance at `t_ref_ns`.
    GroundTruth,
}

impl FrameKind {
    fn as_str(self) -> &'static str {
        match self {
            FrameKind::Reconstruction => "reconstruction",
            FrameKind::GroundTruth => "ground-truth",
        }
    }
}

/// A luminance frame `[H, W]` in [0, 1] at `t_ref_ns`.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Reconstruction or ground truth.
    pub kind: FrameKind,
    /// The method that produced it (`tfp`, `tfi`, `ground-truth`, ...).
    pub method: String,
    /// The instant it shows, nanoseconds on the spike clock.
    pub t_ref_ns: i64,
    /// Wall-clock time spent computing it, nanoseconds.
    pub compute_ns: i64,
    /// The method `auto` chose for this frame (`tfp-256`, `neuspike-fused-8`, ...); `None` (the
    /// key absent) for every other method.
    pub chosen: Option<String>,
    /// The deadline `auto` ran under in budget mode, nanoseconds; `None` (absent) otherwise.
    pub budget_ns: Option<i64>,
    /// Sequence number on its output.
    pub seq: u64,
    /// Luminance in [0, 1].
    pub data: Array2<f32>,
}

impl Message for Frame {
    const TYPE_URN: &'static str = "neuspike/messages/v1/Frame";

    fn data_type() -> DataType {
        DataType::Float32
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        let (h, w) = self.data.dim();
        let mut m = Meta::new();
        m.set_string(meta::KIND, self.kind.as_str());
        m.set_string(meta::METHOD, &self.method);
        m.set_int(meta::WIDTH, int_of(w));
        m.set_int(meta::HEIGHT, int_of(h));
        m.set_int(meta::T_REF_NS, self.t_ref_ns);
        m.set_int(meta::COMPUTE_NS, self.compute_ns);
        if let Some(c) = &self.chosen {
            m.set_string(meta::CHOSEN, c);
        }
        if let Some(b) = self.budget_ns {
            m.set_int(meta::BUDGET_NS, b);
        }
        m.set_int(meta::SEQ, self.seq as i64);
        let values: Vec<f32> = match self.data.as_slice() {
            Some(s) => s.to_vec(),
            None => self.data.iter().copied().collect(),
        };
        (m, Arc::new(Float32Array::from(values)))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        const NAME: &str = "frame";
        let a = floats(NAME, data)?;
        let h = m.size(NAME, meta::HEIGHT)?;
        let w = m.size(NAME, meta::WIDTH)?;
        if a.len() != h.saturating_mul(w) {
            return Err(SchemaError::Inconsistent {
                message: NAME,
                what: format!("payload has {} values, header says {h}x{w}", a.len()),
            });
        }
        non_finite(NAME, a.values())?;
        let kind = match m.string(NAME, meta::KIND)?.as_str() {
            "reconstruction" => FrameKind::Reconstruction,
            "ground-truth" => FrameKind::GroundTruth,
            other => {
                return Err(SchemaError::BadKey {
                    message: NAME,
                    key: meta::KIND,
                    expected: "`reconstruction` or `ground-truth`",
                    found: other.to_string(),
                });
            }
        };
        let data = Array2::from_shape_vec((h, w), a.values().to_vec()).map_err(|e| {
            SchemaError::Inconsistent {
                message: NAME,
                what: e.to_string(),
            }
        })?;
        Ok(Frame {
            kind,
            method: m.string(NAME, meta::METHOD)?,
            t_ref_ns: m.int(NAME, meta::T_REF_NS)?,
            compute_ns: m.int(NAME, meta::COMPUTE_NS)?,
            chosen: match m.contains_key(meta::CHOSEN) {
                true => Some(m.string(NAME, meta::CHOSEN)?),
                false => None,
            },
            budget_ns: match m.contains_key(meta::BUDGET_NS) {
                true => Some(m.int(NAME, meta::BUDGET_NS)?),
                false => None,
            },
            seq: m.uint(NAME, meta::SEQ)?,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn representation_round_trip() {
        let r = Representation {
            kind: RepresentationKind::Isi,
            t_ref_ns: 42,
            seq: 1,
            params: [("window".to_string(), 33.0)].into_iter().collect(),
            data: Array3::from_shape_fn((2, 3, 4), |(c, y, x)| (c * 100 + y * 10 + x) as f32),
        };
        let (mut m, a) = r.to_arrow();
        assert_eq!(Representation::from_arrow(&m, &a).unwrap(), r);
        m.set_string(meta::KIND, "spike-repr");
        let e = Representation::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("`kind`") && e.contains("\"spike-repr\""), "{e}");
    }

    #[test]
    fn frame_round_trip_and_nan_rejected() {
        let f = Frame {
            kind: FrameKind::GroundTruth,
            method: "ground-truth".into(),
            t_ref_ns: 9,
            compute_ns: 0,
            chosen: None,
            budget_ns: None,
            seq: 2,
            data: Array2::from_shape_fn((2, 3), |(y, x)| (y * 3 + x) as f32 / 6.0),
        };
        let (m, a) = f.to_arrow();
        assert_eq!(Frame::from_arrow(&m, &a).unwrap(), f);
        assert!(!m.contains_key(meta::CHOSEN) && !m.contains_key(meta::BUDGET_NS));
        // auto's keys, present only when set, round-trip; a wrong type is named.
        let auto = Frame {
            method: "auto".into(),
            chosen: Some("tfp-256".into()),
            budget_ns: Some(5_000_000),
            ..f.clone()
        };
        let (mut m, a) = auto.to_arrow();
        assert_eq!(Frame::from_arrow(&m, &a).unwrap(), auto);
        m.set_int(meta::CHOSEN, 3);
        let e = Frame::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("chosen"), "{e}");
        let mut g = f.clone();
        g.data[[1, 2]] = f32::NAN;
        let (m, a) = g.to_arrow();
        let e = Frame::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("value 5 is NaN"), "{e}");
    }
}
