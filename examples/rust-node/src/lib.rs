//! A node of one's own, in Rust: the algorithm, pure and testable without dora. This one
//! tone-maps a TFP representation with a gamma curve: `frame = clamp(tfp, 0, 1) ^ gamma`, which
//! lifts the dark parts of a dark scene (`gamma < 1`). Replace [`tone_map`] with your own method;
//! the node around it (`src/main.rs`) stays the same.

use std::time::Instant;

use neuspike_schemas::{Frame, FrameKind, Representation};

/// The node's settings (its `args:` in the graph).
#[derive(Clone, Debug, clap::Args)]
pub struct Settings {
    /// The exponent of the curve, in (0, 10]: below 1 brightens dark pixels.
    #[arg(long, default_value_t = 0.5)]
    pub gamma: f32,
}

impl Settings {
    /// Checks the settings before the node reads anything.
    ///
    /// # Errors
    /// `gamma` is not in (0, 10].
    pub fn check(&self) -> eyre::Result<()> {
        if !(self.gamma > 0.0 && self.gamma <= 10.0) {
            eyre::bail!("--gamma {}: must be in (0, 10]", self.gamma);
        }
        Ok(())
    }
}

/// The frame of a one-channel representation: each value clamped to [0, 1] (NaN counts as 0),
/// raised to `gamma`. Keeps the window's instant and sequence number, so that the sink pairs it
/// with its ground truth and counts it.
///
/// # Errors
/// The representation has more than one channel.
pub fn tone_map(rep: &Representation, gamma: f32) -> eyre::Result<Frame> {
    let start = Instant::now();
    let (c, h, w) = rep.data.dim();
    if c != 1 {
        eyre::bail!(
            "representation {} (seq {}): {c} channels, this node takes one (tfp)",
            rep.kind,
            rep.seq
        );
    }
    let data = rep
        .data
        .to_shape((h, w))
        .map_err(|e| eyre::eyre!("representation seq {}: {e}", rep.seq))?
        .mapv(|v| {
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
            v.powf(gamma)
        });
    Ok(Frame {
        kind: FrameKind::Reconstruction,
        method: "gamma".into(),
        t_ref_ns: rep.t_ref_ns,
        compute_ns: i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX),
        chosen: None,
        budget_ns: None,
        seq: rep.seq,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::RepresentationKind;

    fn rep(values: &[f32], channels: usize) -> Representation {
        Representation {
            kind: RepresentationKind::Tfp,
            t_ref_ns: 42,
            seq: 3,
            params: Default::default(),
            data: ndarray::Array3::from_shape_vec(
                (channels, 1, values.len() / channels),
                values.to_vec(),
            )
            .expect("shape"),
        }
    }

    #[test]
    fn values_are_clamped_then_raised_to_gamma() {
        let f = tone_map(&rep(&[0.25, 1.0, 2.0, -1.0, f32::NAN, 0.0], 1), 0.5).expect("frame");
        assert_eq!(
            f.data.as_slice().expect("contiguous"),
            &[0.5, 1.0, 1.0, 0.0, 0.0, 0.0]
        );
        assert_eq!((f.seq, f.t_ref_ns, f.method.as_str()), (3, 42, "gamma"));
        assert!(tone_map(&rep(&[0.0; 4], 2), 0.5).is_err());
        assert!(Settings { gamma: 0.0 }.check().is_err());
        assert!(Settings { gamma: f32::NAN }.check().is_err());
        assert!(Settings { gamma: 2.2 }.check().is_ok());
    }
}
