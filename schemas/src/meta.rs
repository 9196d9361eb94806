//! Metadata keys and typed access to a message's header.
//!
//! The header is a map from key to [`Parameter`], the same shape as dora's metadata parameters;
//! the node runtime (`neuspike-runtime`) converts between the two, so this crate and everything
//! that reads messages build without dora.

use std::collections::BTreeMap;

/// A message's header: metadata parameters by key.
pub type Meta = BTreeMap<String, Parameter>;

/// One metadata value.
#[derive(Clone, Debug, PartialEq)]
pub enum Parameter {
    /// A boolean.
    Bool(bool),
    /// A signed 64-bit integer.
    Integer(i64),
    /// A 64-bit float.
    Float(f64),
    /// A UTF-8 string.
    String(String),
    /// A value of a kind no neuspike message uses (a list, a timestamp), described for errors.
    Other(String),
}

/// Width of the sensor in pixels.
pub const WIDTH: &str = "width";
/// Height of the sensor in pixels.
pub const HEIGHT: &str = "height";
/// Sequence number of a message on its output, counting from 0.
pub const SEQ: &str = "seq";
/// Index of the first spike plane of a chunk or window since the start of the stream.
pub const FIRST_PLANE: &str = "first_plane";
/// Number of spike planes in a chunk or window.
pub const N_PLANES: &str = "n_planes";
/// Time of the first plane, in nanoseconds on the spike clock.
pub const T_FIRST_NS: &str = "t_first_ns";
/// Time between two spike planes, in nanoseconds.
pub const PLANE_PERIOD_NS: &str = "plane_period_ns";
/// Start of the half-open interval an event batch covers, in nanoseconds.
pub const T_START_NS: &str = "t_start_ns";
/// End of the half-open interval an event batch covers, in nanoseconds.
pub const T_END_NS: &str = "t_end_ns";
/// The reconstruction instant, in nanoseconds on the spike clock.
pub const T_REF_NS: &str = "t_ref_ns";
/// Global index of the reference plane of an aligned window.
pub const REF_PLANE: &str = "ref_plane";
/// Kind of a representation (`tfp`, `isi`, ...) or frame (`reconstruction`, `ground-truth`).
pub const KIND: &str = "kind";
/// Number of channels of a representation tensor.
pub const CHANNELS: &str = "channels";
/// Reconstruction method that produced a frame.
pub const METHOD: &str = "method";
/// Wall-clock compute time of a frame, in nanoseconds.
pub const COMPUTE_NS: &str = "compute_ns";
/// Frame (optional): the method `auto` chose (choosing per region: its tiles' methods joined by
/// `+`, most tiles first, `reused` for tiles that kept the last frame's pixels).
pub const CHOSEN: &str = "chosen";
/// Frame (optional): `auto`'s budget per frame, nanoseconds.
pub const BUDGET_NS: &str = "budget_ns";
/// Prefix of the numeric parameters of a representation (`param.window`, `param.tau_ns`).
pub const PARAM_PREFIX: &str = "param.";
/// Luminance per unit firing rate (per tick), a float, when the spike source knows it.
pub const LUM_PER_RATE: &str = "lum_per_rate";
/// Marks the end-of-stream message.
pub const EOS: &str = "eos";
/// A message's place among those its node sent on its output (from 0; the node runtime stamps
/// it). A gap here is messages lost on the way; a gap in `seq` alone is messages never made (a
/// window skipped upstream), which took no credit.
pub const LINK_N: &str = "link_n";
/// On an end-of-stream marker: the stream was cut short, because its node or a node upstream of
/// it failed (a bool; absent is false).
pub const CUT: &str = "cut";
/// Number of messages sent on an output before its end-of-stream marker.
pub const COUNT: &str = "count";
/// Wall-clock time, Unix nanoseconds, at which the newest camera data a message derives from
/// left its source (the node runtime stamps it; a sink measures latency from it).
pub const ORIGIN_UNIX_NS: &str = "origin_unix_ns";

/// Why a message could not be decoded. Each variant names what was wrong and the value found.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SchemaError {
    /// A required metadata key is absent.
    #[error("{message}: metadata key `{key}` is missing")]
    MissingKey {
        /// The message type.
        message: &'static str,
        /// The missing key.
        key: &'static str,
    },
    /// A metadata key has the wrong type or an invalid value.
    #[error("{message}: metadata key `{key}` is {found}, expected {expected}")]
    BadKey {
        /// The message type.
        message: &'static str,
        /// The key.
        key: &'static str,
        /// What was expected.
        expected: &'static str,
        /// What was found.
        found: String,
    },
    /// The payload has the wrong Arrow type.
    #[error("{message}: payload has Arrow type {found}, expected {expected}")]
    BadType {
        /// The message type.
        message: &'static str,
        /// The expected type.
        expected: String,
        /// The type found.
        found: String,
    },
    /// The payload does not agree with the header.
    #[error("{message}: {what}")]
    Inconsistent {
        /// The message type.
        message: &'static str,
        /// What disagrees, with the values.
        what: String,
    },
}

/// Typed access to metadata parameters with errors that name the key.
pub trait MetaExt {
    /// An integer parameter.
    fn int(&self, message: &'static str, key: &'static str) -> Result<i64, SchemaError>;
    /// A non-negative integer parameter.
    fn uint(&self, message: &'static str, key: &'static str) -> Result<u64, SchemaError>;
    /// A positive integer that is a size (width, height, count).
    fn size(&self, message: &'static str, key: &'static str) -> Result<usize, SchemaError>;
    /// A string parameter.
    fn string(&self, message: &'static str, key: &'static str) -> Result<String, SchemaError>;
    /// A boolean parameter, `false` when absent.
    fn flag(&self, key: &str) -> bool;
    /// The optional positive, finite `lum_per_rate` calibration.
    fn lum_per_rate(&self, message: &'static str) -> Result<Option<f64>, SchemaError>;
    /// A float parameter (integers are accepted too).
    fn float(&self, message: &'static str, key: &'static str) -> Result<f64, SchemaError>;
    /// Sets an integer parameter.
    fn set_int(&mut self, key: &str, value: i64);
    /// Sets a string parameter.
    fn set_string(&mut self, key: &str, value: &str);
}

fn describe(p: &Parameter) -> String {
    match p {
        Parameter::Bool(b) => format!("the bool {b}"),
        Parameter::Integer(i) => format!("the integer {i}"),
        Parameter::String(s) => format!("the string {s:?}"),
        Parameter::Float(f) => format!("the float {f}"),
        Parameter::Other(what) => what.clone(),
    }
}

impl MetaExt for Meta {
    fn int(&self, message: &'static str, key: &'static str) -> Result<i64, SchemaError> {
        match self.get(key) {
            None => Err(SchemaError::MissingKey { message, key }),
            Some(Parameter::Integer(i)) => Ok(*i),
            Some(other) => Err(SchemaError::BadKey {
                message,
                key,
                expected: "an integer",
                found: describe(other),
            }),
        }
    }

    fn uint(&self, message: &'static str, key: &'static str) -> Result<u64, SchemaError> {
        let v = self.int(message, key)?;
        u64::try_from(v).map_err(|_| SchemaError::BadKey {
            message,
            key,
            expected: "a non-negative integer",
            found: v.to_string(),
        })
    }

    fn size(&self, message: &'static str, key: &'static str) -> Result<usize, SchemaError> {
        let v = self.int(message, key)?;
        match usize::try_from(v) {
            Ok(s) if s <= u32::MAX as usize => Ok(s),
            _ => Err(SchemaError::BadKey {
                message,
                key,
                expected: "a size in 0..=4294967295",
                found: v.to_string(),
            }),
        }
    }

    fn string(&self, message: &'static str, key: &'static str) -> Result<String, SchemaError> {
        match self.get(key) {
            None => Err(SchemaError::MissingKey { message, key }),
            Some(Parameter::String(s)) => Ok(s.clone()),
            Some(other) => Err(SchemaError::BadKey {
                message,
                key,
                expected: "a string",
                found: describe(other),
            }),
        }
    }

    fn lum_per_rate(&self, message: &'static str) -> Result<Option<f64>, SchemaError> {
        if !self.contains_key(LUM_PER_RATE) {
            return Ok(None);
        }
        let g = self.float(message, LUM_PER_RATE)?;
        if g.is_finite() && g > 0.0 {
            Ok(Some(g))
        } else {
            Err(SchemaError::BadKey {
                message,
                key: LUM_PER_RATE,
                expected: "a positive finite number",
                found: g.to_string(),
            })
        }
    }

    fn float(&self, message: &'static str, key: &'static str) -> Result<f64, SchemaError> {
        match self.get(key) {
            None => Err(SchemaError::MissingKey { message, key }),
            Some(Parameter::Float(f)) => Ok(*f),
            Some(Parameter::Integer(i)) => Ok(*i as f64),
            Some(other) => Err(SchemaError::BadKey {
                message,
                key,
                expected: "a number",
                found: describe(other),
            }),
        }
    }

    fn flag(&self, key: &str) -> bool {
        matches!(self.get(key), Some(Parameter::Bool(true)))
    }

    fn set_int(&mut self, key: &str, value: i64) {
        self.insert(key.to_string(), Parameter::Integer(value));
    }

    fn set_string(&mut self, key: &str, value: &str) {
        self.insert(key.to_string(), Parameter::String(value.to_string()));
    }
}

/// Converts a size to the metadata integer type (sizes come from `usize` fields bounded by
/// [`MetaExt::size`], so the conversion saturates only for impossible values).
pub(crate) fn int_of(v: usize) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// Checks that a payload has the expected Arrow type.
pub(crate) fn check_type(
    message: &'static str,
    expected: &arrow::datatypes::DataType,
    found: &arrow::datatypes::DataType,
) -> Result<(), SchemaError> {
    if expected == found {
        Ok(())
    } else {
        Err(SchemaError::BadType {
            message,
            expected: expected.to_string(),
            found: found.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_key_and_value() {
        let mut m = Meta::new();
        m.set_string(WIDTH, "four hundred");
        let e = m.size("spike chunk", WIDTH).unwrap_err().to_string();
        assert!(e.contains("width") && e.contains("four hundred"), "{e}");
        let e = m.int("spike chunk", HEIGHT).unwrap_err().to_string();
        assert!(e.contains("height") && e.contains("missing"), "{e}");
        m.set_int(HEIGHT, -3);
        let e = m.size("spike chunk", HEIGHT).unwrap_err().to_string();
        assert!(e.contains("-3"), "{e}");
    }
}
