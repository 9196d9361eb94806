//! Spike chunks: N consecutive bit-packed spike planes.

use std::sync::Arc;

use arrow::array::{Array, ArrayRef, UInt8Array};
use arrow::datatypes::DataType;
use ndarray::{ArrayView3, ArrayViewMut3};

use crate::Message;
use crate::limits::MAX_PLANE;
use crate::meta::{self, Meta, MetaExt, SchemaError, check_type, int_of};

const NAME: &str = "spike chunk";

/// Bytes one plane of `width x height` takes: `ceil(width * height / 8)`; every plane starts on a
/// byte boundary. For 400x250 this is the PKU `.dat` plane of 12,500 bytes.
pub fn bytes_per_plane(width: usize, height: usize) -> usize {
    (width * height).div_ceil(8)
}

/// The pixels that fired in one packed plane of `n` pixels, ascending (bits past `n`, the
/// last byte's padding, are ignored).
pub fn fired_pixels(plane: &[u8], n: usize) -> impl Iterator<Item = usize> + '_ {
    plane.iter().enumerate().flat_map(move |(byte, &b)| {
        let mut b = b;
        std::iter::from_fn(move || {
            if b == 0 {
                return None;
            }
            let i = byte * 8 + b.trailing_zeros() as usize;
            b &= b - 1;
            Some(i)
        })
        .filter(move |&i| i < n)
    })
}

/// N consecutive spike planes of `height x width`, bit-packed row-major, rows top-down, pixel
/// `k = y * width + x` at bit `k & 7` (least significant first) of byte `k >> 3` of its plane
/// (the PKU `.dat` packing, except that `.dat` files store rows bottom-up).
///
/// Plane `i` of the chunk has global index `first_plane + i` and fires at
/// `t_first_ns + i * plane_period_ns`.
#[derive(Clone, Debug, PartialEq)]
pub struct SpikeChunk {
    /// Sensor width in pixels.
    pub width: usize,
    /// Sensor height in pixels.
    pub height: usize,
    /// Global index of the first plane.
    pub first_plane: u64,
    /// Number of planes.
    pub n_planes: usize,
    /// Time of the first plane, in nanoseconds.
    pub t_first_ns: i64,
    /// Time between planes, in nanoseconds (> 0).
    pub plane_period_ns: i64,
    /// Sequence number on its output.
    pub seq: u64,
    /// `n_planes * bytes_per_plane(width, height)` packed bytes.
    pub bits: Vec<u8>,
    /// Luminance per unit firing rate (`phi / light_scale` for the simulator), when the source
    /// knows its calibration: a pixel firing `r` spikes per tick sees luminance `r * lum_per_rate`.
    pub lum_per_rate: Option<f64>,
}

impl SpikeChunk {
    /// Time of plane `i` of this chunk (saturating at the ends of `i64`).
    pub fn plane_time_ns(&self, i: usize) -> i64 {
        self.t_first_ns
            .saturating_add(int_of(i).saturating_mul(self.plane_period_ns))
    }

    /// The chunk's header with no planes (`n_planes` kept, `bits` empty): for building a chunk
    /// of other planes with the same geometry, clock, sequence number and calibration.
    pub fn header_only(&self) -> SpikeChunk {
        SpikeChunk {
            bits: Vec::new(),
            ..*self
        }
    }

    /// The packed bytes of plane `i`.
    pub fn plane_bits(&self, i: usize) -> &[u8] {
        let b = bytes_per_plane(self.width, self.height);
        &self.bits[i * b..(i + 1) * b]
    }

    /// Unpacks all planes into `dst` shaped `[n_planes, height, width]` (values 0/1).
    pub fn unpack_into(&self, dst: ArrayViewMut3<u8>) {
        unpack_planes_into(&self.bits, dst);
    }

    /// Total number of spikes in the chunk.
    pub fn spike_count(&self) -> u64 {
        let per = bytes_per_plane(self.width, self.height);
        let valid_bits = self.width * self.height;
        let mut total = 0u64;
        for plane in self.bits.chunks_exact(per.max(1)) {
            let full = valid_bits / 8;
            total += plane[..full]
                .iter()
                .map(|b| u64::from(b.count_ones()))
                .sum::<u64>();
            if !valid_bits.is_multiple_of(8) {
                let mask = (1u8 << (valid_bits % 8)) - 1;
                total += u64::from((plane[full] & mask).count_ones());
            }
        }
        total
    }
}

/// Packs `planes` (`[N, H, W]`, non-zero = spike) into the wire layout.
pub fn pack_planes(planes: ArrayView3<u8>) -> Vec<u8> {
    let (n, h, w) = planes.dim();
    let per = bytes_per_plane(w, h);
    let mut out = vec![0u8; n * per];
    for (plane, dst) in planes.outer_iter().zip(out.chunks_exact_mut(per.max(1))) {
        for (k, &v) in plane.iter().enumerate() {
            if v != 0 {
                dst[k >> 3] |= 1 << (k & 7);
            }
        }
    }
    out
}

/// Unpacks packed planes into `dst` (`[N, H, W]`, 0/1). `bits` must hold at least
/// `N * bytes_per_plane(W, H)` bytes (checked by [`SpikeChunk::from_arrow`]).
pub fn unpack_planes_into(bits: &[u8], mut dst: ArrayViewMut3<u8>) {
    let (_, h, w) = dst.dim();
    let per = bytes_per_plane(w, h);
    for (mut plane, src) in dst.outer_iter_mut().zip(bits.chunks_exact(per.max(1))) {
        for (k, v) in plane.iter_mut().enumerate() {
            *v = (src[k >> 3] >> (k & 7)) & 1;
        }
    }
}

impl Message for SpikeChunk {
    const TYPE_URN: &'static str = "neuspike/messages/v1/SpikeChunk";

    fn data_type() -> DataType {
        DataType::UInt8
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        (self.header(), Arc::new(UInt8Array::from(self.bits.clone())))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        Self::decode(m, data)
    }
}

impl SpikeChunk {
    /// The metadata header alone (the aligned window reuses it without encoding the planes).
    pub fn header(&self) -> Meta {
        let mut m = Meta::new();
        m.set_int(meta::WIDTH, int_of(self.width));
        m.set_int(meta::HEIGHT, int_of(self.height));
        m.set_int(meta::FIRST_PLANE, self.first_plane as i64);
        m.set_int(meta::N_PLANES, int_of(self.n_planes));
        m.set_int(meta::T_FIRST_NS, self.t_first_ns);
        m.set_int(meta::PLANE_PERIOD_NS, self.plane_period_ns);
        m.set_int(meta::SEQ, self.seq as i64);
        if let Some(g) = self.lum_per_rate {
            m.insert(meta::LUM_PER_RATE.to_string(), meta::Parameter::Float(g));
        }
        m
    }

    fn decode(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        check_type(NAME, &Self::data_type(), data.data_type())?;
        let width = m.size(NAME, meta::WIDTH)?;
        let height = m.size(NAME, meta::HEIGHT)?;
        let n_planes = m.size(NAME, meta::N_PLANES)?;
        let first_plane = m.uint(NAME, meta::FIRST_PLANE)?;
        let t_first_ns = m.int(NAME, meta::T_FIRST_NS)?;
        let plane_period_ns = m.int(NAME, meta::PLANE_PERIOD_NS)?;
        let seq = m.uint(NAME, meta::SEQ)?;
        crate::limits::check_sensor(NAME, width, height)?;
        if plane_period_ns <= 0 {
            return Err(SchemaError::BadKey {
                message: NAME,
                key: meta::PLANE_PERIOD_NS,
                expected: "a positive period",
                found: plane_period_ns.to_string(),
            });
        }
        // The stream's planes and clock stay far inside i64 (a plane's time is
        // `t_first + k * period` downstream).
        let last_plane = first_plane.checked_add(n_planes as u64);
        if last_plane.is_none_or(|p| p > MAX_PLANE) {
            return Err(SchemaError::BadKey {
                message: NAME,
                key: meta::FIRST_PLANE,
                expected: "a plane number that, with the chunk's planes, stays within 2^48",
                found: first_plane.to_string(),
            });
        }
        let t_last = (n_planes as i64)
            .checked_mul(plane_period_ns)
            .and_then(|d| t_first_ns.checked_add(d))
            .filter(|_| {
                (first_plane as i64)
                    .checked_mul(plane_period_ns)
                    .is_some_and(|back| t_first_ns.checked_sub(back).is_some())
            });
        if t_last.is_none() {
            return Err(SchemaError::Inconsistent {
                message: NAME,
                what: format!(
                    "planes {first_plane}.. every {plane_period_ns} ns from {t_first_ns} ns \
                     leave the 64-bit clock"
                ),
            });
        }
        let expected = n_planes
            .checked_mul(bytes_per_plane(width, height))
            .ok_or_else(|| SchemaError::Inconsistent {
                message: NAME,
                what: format!("{n_planes} planes of {width}x{height} overflow"),
            })?;
        if data.null_count() != 0 {
            return Err(SchemaError::Inconsistent {
                message: NAME,
                what: format!("payload has {} null bytes", data.null_count()),
            });
        }
        let bytes =
            data.as_any()
                .downcast_ref::<UInt8Array>()
                .ok_or_else(|| SchemaError::BadType {
                    message: NAME,
                    expected: "UInt8".into(),
                    found: data.data_type().to_string(),
                })?;
        if bytes.len() != expected {
            return Err(SchemaError::Inconsistent {
                message: NAME,
                what: format!(
                    "payload has {} bytes, header says {n_planes} planes of {width}x{height} = {expected} bytes",
                    bytes.len()
                ),
            });
        }
        Ok(SpikeChunk {
            width,
            height,
            first_plane,
            n_planes,
            t_first_ns,
            plane_period_ns,
            seq,
            bits: bytes.values().to_vec(),
            lum_per_rate: m.lum_per_rate(NAME)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use proptest::prelude::*;

    fn chunk_header(first_plane: u64, t_first_ns: i64) -> (Meta, ArrayRef) {
        SpikeChunk {
            width: 8,
            height: 2,
            first_plane,
            n_planes: 1,
            t_first_ns,
            plane_period_ns: 50_000,
            seq: 0,
            bits: vec![0; 2],
            lum_per_rate: None,
        }
        .to_arrow()
    }

    #[test]
    fn a_chunk_whose_planes_or_clock_reach_past_the_limits_is_refused() {
        let (m, a) = chunk_header(1_000, 50_000_000);
        assert!(SpikeChunk::from_arrow(&m, &a).is_ok());
        let (m, a) = chunk_header(i64::MAX as u64 - 1, 0);
        let e = SpikeChunk::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("first_plane") && e.contains("2^48"), "{e}");
        let (m, a) = chunk_header(0, i64::MAX - 10);
        let e = SpikeChunk::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("leave the 64-bit clock"), "{e}");
        let (mut m, a) = chunk_header(0, 0);
        m.set_int(meta::WIDTH, 65_535);
        m.set_int(meta::HEIGHT, 65_535);
        let e = SpikeChunk::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("65535x65535"), "{e}");
    }

    #[test]
    fn packing_is_lsb_first_row_major() {
        let mut p = Array3::<u8>::zeros((1, 2, 8));
        p[[0, 0, 0]] = 1; // k = 0 -> byte 0 bit 0
        p[[0, 1, 2]] = 1; // k = 10 -> byte 1 bit 2
        let bits = pack_planes(p.view());
        assert_eq!(bits, vec![0b0000_0001, 0b0000_0100]);
    }

    #[test]
    fn odd_sizes_pad_each_plane() {
        assert_eq!(bytes_per_plane(3, 3), 2);
        assert_eq!(bytes_per_plane(400, 250), 12_500);
    }

    proptest! {
        #[test]
        fn pack_unpack_round_trip(n in 1usize..4, h in 1usize..7, w in 1usize..9, seed in any::<u64>()) {
            let mut s = seed | 1;
            let p = Array3::from_shape_fn((n, h, w), |_| { s ^= s << 13; s ^= s >> 7; s ^= s << 17; (s & 1) as u8 });
            let chunk = SpikeChunk { width: w, height: h, first_plane: 5, n_planes: n, t_first_ns: -7,
                plane_period_ns: 50_000, seq: 3, bits: pack_planes(p.view()), lum_per_rate: Some(2.0) };
            let (m, a) = chunk.to_arrow();
            let back = SpikeChunk::from_arrow(&m, &a).unwrap();
            prop_assert_eq!(&back, &chunk);
            let mut u = Array3::<u8>::zeros((n, h, w));
            back.unpack_into(u.view_mut());
            prop_assert_eq!(&u, &p);
            prop_assert_eq!(back.spike_count(), p.iter().map(|&v| u64::from(v)).sum::<u64>());
        }
    }

    #[test]
    fn size_mismatch_is_named() {
        let chunk = SpikeChunk {
            width: 4,
            height: 2,
            first_plane: 0,
            n_planes: 2,
            t_first_ns: 0,
            plane_period_ns: 1,
            seq: 0,
            bits: vec![0; 2],
            lum_per_rate: None,
        };
        let (mut m, a) = chunk.to_arrow();
        m.set_int(meta::N_PLANES, 3);
        let e = SpikeChunk::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("2 bytes") && e.contains("3 planes"), "{e}");
        m.set_int(meta::N_PLANES, 2);
        m.set_int(meta::PLANE_PERIOD_NS, 0);
        let e = SpikeChunk::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.contains("plane_period_ns") && e.contains('0'), "{e}");
    }
}

#[cfg(test)]
mod fired_tests {
    use super::*;

    #[test]
    fn fired_pixels_are_the_set_bits_below_n() {
        // Pixels 0, 3, 9 and 12 of 11 (12 is padding).
        let plane = [0b0000_1001u8, 0b0001_0010];
        assert_eq!(fired_pixels(&plane, 11).collect::<Vec<_>>(), vec![0, 3, 9]);
        assert_eq!(
            fired_pixels(&plane, 16).collect::<Vec<_>>(),
            vec![0, 3, 9, 12]
        );
        assert_eq!(fired_pixels(&[], 0).count(), 0);
    }
}
