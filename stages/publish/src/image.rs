//! Frames as ROS 2 images: the pixel encodings of `sensor_msgs/msg/Image` (the CDR, keys and
//! tokens are `neuspike_net::ros2`).

use neuspike_image::{BitDepth, grey_levels};
use neuspike_net::ros2::image_cdr;
use neuspike_schemas::Frame;

/// How a frame's pixels go into an Image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Encoding {
    /// 8-bit grey, `round(clamp(v) * 255)` as the sink's PNGs.
    Mono8,
    /// 16-bit grey (little-endian), `round(clamp(v) * 65535)`.
    Mono16,
    /// The luminance itself, 32-bit float (little-endian), not clamped.
    #[value(name = "32FC1")]
    Float32,
}

impl Encoding {
    /// The `encoding` string of the Image.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Mono8 => "mono8",
            Encoding::Mono16 => "mono16",
            Encoding::Float32 => "32FC1",
        }
    }

    fn bytes_per_pixel(self) -> usize {
        match self {
            Encoding::Mono8 => 1,
            Encoding::Mono16 => 2,
            Encoding::Float32 => 4,
        }
    }
}

/// `frame` as an Image in CDR, stamped `stamp_ns`, in `encoding`.
pub fn frame_image(frame: &Frame, stamp_ns: i64, frame_id: &str, encoding: Encoding) -> Vec<u8> {
    let (h, w) = frame.data.dim();
    let data: Vec<u8> = match encoding {
        Encoding::Mono8 => grey_levels(frame.data.view(), BitDepth::Eight)
            .into_iter()
            .map(|v| v as u8)
            .collect(),
        Encoding::Mono16 => grey_levels(frame.data.view(), BitDepth::Sixteen)
            .into_iter()
            .flat_map(u16::to_le_bytes)
            .collect(),
        Encoding::Float32 => frame.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
    };
    let step = w * encoding.bytes_per_pixel();
    image_cdr(
        stamp_ns,
        frame_id,
        u32::try_from(h).unwrap_or(u32::MAX),
        u32::try_from(w).unwrap_or(u32::MAX),
        encoding.name(),
        u32::try_from(step).unwrap_or(u32::MAX),
        &data,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::FrameKind;

    #[test]
    fn frames_go_into_images_in_each_encoding() {
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: 0,
            compute_ns: 0,
            chosen: None,
            budget_ns: None,
            seq: 0,
            data: ndarray::array![[0.0f32, 1.0, 0.5], [2.0, -1.0, f32::NAN]],
        };
        let tail = |b: &[u8], n: usize| b[b.len() - n..].to_vec();
        let m8 = frame_image(&frame, 0, "f", Encoding::Mono8);
        assert_eq!(tail(&m8, 6), [0, 255, 128, 255, 0, 0]);
        let m16 = frame_image(&frame, 0, "f", Encoding::Mono16);
        assert_eq!(tail(&m16, 6), [0xff, 0xff, 0, 0, 0, 0]);
        let f32s = frame_image(&frame, 0, "f", Encoding::Float32);
        assert_eq!(tail(&f32s, 4), f32::NAN.to_le_bytes());
        // step, then the data length, just before the data.
        let n = f32s.len();
        assert_eq!(f32s[n - 24 - 8..n - 24 - 4], 12u32.to_le_bytes());
        assert_eq!(f32s[n - 24 - 4..n - 24], 24u32.to_le_bytes());
    }
}
