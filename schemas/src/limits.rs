//! The limits a message's header is checked against before anything is allocated for it or
//! looped over: what a sensor may be, how far a stream's planes and clock may reach. A message
//! from another process or another machine (a zenoh key, a ROS 2 topic, a recording) is
//! untrusted: a forged header claiming a 65535 x 65535 sensor must be refused, not allocated.

use std::sync::OnceLock;

use crate::meta::SchemaError;

/// The widest and highest sensor a message may describe: pixel coordinates are 16-bit.
pub const MAX_SENSOR_SIDE: usize = 65_535;

/// The most pixels a sensor may have unless [`MAX_SENSOR_PIXELS_ENV`] says otherwise: 4096 x
/// 4096 (16.8 Mpx), four times the largest event sensors made (1280 x 720, 1280 x 960) and 168
/// times the Vidar's 400 x 250. A node's per-pixel state is a few planes of this: hundreds of
/// MB at most, where 65535 x 65535 would be tens of GB.
pub const DEFAULT_MAX_SENSOR_PIXELS: usize = 1 << 24;

/// The environment variable that raises (or lowers) [`DEFAULT_MAX_SENSOR_PIXELS`] for a node,
/// a positive integer (set in a graph node's `env:`). Read once, at the first message.
pub const MAX_SENSOR_PIXELS_ENV: &str = "NEUSPIKE_MAX_SENSOR_PIXELS";

/// The highest plane number a spike stream may reach: 2^48, 223 years of planes at 40 kHz, so
/// that a plane's time (`t0 + k * period`) and any stride over planes stay far inside `i64`.
pub const MAX_PLANE: u64 = 1 << 48;

/// The most pixels a sensor may have in this process: [`MAX_SENSOR_PIXELS_ENV`] when it holds a
/// positive integer, else [`DEFAULT_MAX_SENSOR_PIXELS`] (a value that is not one is reported once,
/// on stderr through `tracing`, and the default kept).
pub fn max_sensor_pixels() -> usize {
    static MAX: OnceLock<usize> = OnceLock::new();
    *MAX.get_or_init(|| match std::env::var(MAX_SENSOR_PIXELS_ENV) {
        Ok(v) => match v.trim().parse::<usize>() {
            Ok(n) if n > 0 => n,
            _ => {
                tracing::warn!(
                    "{MAX_SENSOR_PIXELS_ENV} = {v:?} is not a positive integer: \
                     {DEFAULT_MAX_SENSOR_PIXELS} pixels kept"
                );
                DEFAULT_MAX_SENSOR_PIXELS
            }
        },
        Err(_) => DEFAULT_MAX_SENSOR_PIXELS,
    })
}

/// Checks a sensor of `width x height` that a `message` describes against [`MAX_SENSOR_SIDE`] and
/// [`max_sensor_pixels`].
///
/// # Errors
/// A side is 0 or above [`MAX_SENSOR_SIDE`], or the pixels exceed the limit: the message names
/// the sensor and the limit.
pub fn check_sensor(message: &'static str, width: usize, height: usize) -> Result<(), SchemaError> {
    sensor_within(message, width, height, max_sensor_pixels())
}

fn sensor_within(
    message: &'static str,
    width: usize,
    height: usize,
    max_pixels: usize,
) -> Result<(), SchemaError> {
    let what = if width == 0 || height == 0 {
        format!("empty sensor {width}x{height}")
    } else if width > MAX_SENSOR_SIDE || height > MAX_SENSOR_SIDE {
        format!("sensor {width}x{height}: a side above {MAX_SENSOR_SIDE}")
    } else if width * height > max_pixels {
        format!(
            "sensor {width}x{height} has {} pixels, above the limit of {max_pixels} \
             ({MAX_SENSOR_PIXELS_ENV} raises it)",
            width * height
        )
    } else {
        return Ok(());
    };
    Err(SchemaError::Inconsistent { message, what })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sensor_is_refused_past_a_side_or_the_pixel_limit() {
        assert!(sensor_within("m", 400, 250, 100_000).is_ok());
        let e = sensor_within("m", 65_535, 65_535, DEFAULT_MAX_SENSOR_PIXELS).unwrap_err();
        assert!(e.to_string().contains("4294836225 pixels"), "{e}");
        assert!(e.to_string().contains(MAX_SENSOR_PIXELS_ENV), "{e}");
        let e = sensor_within("m", 70_000, 1, usize::MAX).unwrap_err();
        assert!(e.to_string().contains("a side above 65535"), "{e}");
        let e = sensor_within("m", 0, 5, usize::MAX).unwrap_err();
        assert!(e.to_string().contains("empty sensor 0x5"), "{e}");
        assert!(sensor_within("m", 4096, 4096, DEFAULT_MAX_SENSOR_PIXELS).is_ok());
        assert!(sensor_within("m", 4097, 4096, DEFAULT_MAX_SENSOR_PIXELS).is_err());
    }
}
