//! The represent node's stage: every representation kind computed from an aligned window, the
//! dispatch the node and `neuspike dataset` share.

use std::collections::BTreeMap;

use ndarray::{Array2, Array3, Axis};
use neuspike_schemas::{AlignedWindow, Representation, RepresentationKind};

use crate::{
    EventSlice, RepresentError, StpFilter, StpParams, TIME_SURFACE_CHANNELS, VoxelNorm,
    event_integration_into, event_stack_into, integration_instants, isi_packed_into,
    spike_representation_packed_into, tfp_packed_into, time_surface_into, voxel_grid_into,
};

/// The most channels or time bins a representation may have (`--repr-channels`,
/// `--ei-channels`, `--voxel-bins`, `--stack-bins`): 4096, 128 times the paper's 32, so that a
/// typo cannot ask for a representation of hundreds of GB.
pub const MAX_CHANNELS: i64 = 4096;

/// The represent stage's settings (the node's `args:`).
#[derive(Clone, Debug, PartialEq, clap::Args)]
pub struct RepresentConfig {
    /// TFP window in planes, centred on the reference plane (default: the whole aligned window).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub tfp_planes: Option<u32>,
    /// Channels of the NeuSpike-Net spike representation (1 ISI + N-1 planes).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(2..=MAX_CHANNELS))]
    pub repr_channels: u32,
    /// Channels of the event integration (instants evenly spaced over the window).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=MAX_CHANNELS))]
    pub ei_channels: u32,
    /// Decay constant tau of the event integration (paper Eq. 8), nanoseconds.
    #[arg(long, default_value_t = 500_000.0)]
    pub tau_ns: f64,
    /// TFSTP (`stp`): the synapse's release probability at rest, U, in (0, 1).
    #[arg(long, default_value_t = StpParams::default().u0)]
    pub stp_u0: f64,
    /// TFSTP (`stp`): the facilitation increment per spike, f, in (0, 1].
    #[arg(long, default_value_t = StpParams::default().f)]
    pub stp_f: f64,
    /// TFSTP (`stp`): the resources' recovery time constant D, in planes (ticks).
    #[arg(long, default_value_t = StpParams::default().tau_d_ticks)]
    pub stp_tau_d_ticks: f64,
    /// TFSTP (`stp`): the facilitation's time constant F, in planes (ticks).
    #[arg(long, default_value_t = StpParams::default().tau_f_ticks)]
    pub stp_tau_f_ticks: f64,
    /// `voxel_grid`: time bins of E2VID's voxel grid (normalised as E2VID: the non-zero voxels
    /// to mean 0 and standard deviation 1).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=MAX_CHANNELS))]
    pub voxel_bins: u32,
    /// `event_stack`: time bins of the event stack.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=MAX_CHANNELS))]
    pub stack_bins: u32,
    /// `time_surface`: decay constant of the time surface, nanoseconds (> 0, inf allowed).
    #[arg(long, default_value_t = 500_000.0)]
    pub surface_tau_ns: f64,
}

impl Default for RepresentConfig {
    fn default() -> Self {
        let stp = StpParams::default();
        RepresentConfig {
            tfp_planes: None,
            repr_channels: 32,
            ei_channels: 32,
            tau_ns: 500_000.0,
            stp_u0: stp.u0,
            stp_f: stp.f,
            stp_tau_d_ticks: stp.tau_d_ticks,
            stp_tau_f_ticks: stp.tau_f_ticks,
            voxel_bins: 5,
            stack_bins: 5,
            surface_tau_ns: 500_000.0,
        }
    }
}

impl RepresentConfig {
    /// TFSTP's synapse parameters.
    pub fn stp_params(&self) -> StpParams {
        StpParams {
            u0: self.stp_u0,
            f: self.stp_f,
            tau_d_ticks: self.stp_tau_d_ticks,
            tau_f_ticks: self.stp_tau_f_ticks,
        }
    }

    /// Checks the settings: `tau_ns` must be `>= 0` and `surface_tau_ns` `> 0` (infinity allowed
    /// for both: no decay), the synapse's parameters as [`StpParams::check`] says.
    pub fn check(&self) -> Result<(), RepresentError> {
        if self.tau_ns.is_nan() || self.tau_ns < 0.0 {
            return Err(RepresentError::Param {
                name: "tau-ns",
                value: self.tau_ns.to_string(),
                reason: "must be >= 0 (inf allowed)",
            });
        }
        if self.surface_tau_ns.is_nan() || self.surface_tau_ns <= 0.0 {
            return Err(RepresentError::Param {
                name: "surface-tau-ns",
                value: self.surface_tau_ns.to_string(),
                reason: "must be > 0 (inf allowed)",
            });
        }
        for (name, value) in [
            ("repr-channels", self.repr_channels),
            ("ei-channels", self.ei_channels),
            ("voxel-bins", self.voxel_bins),
            ("stack-bins", self.stack_bins),
        ] {
            if value == 0 || i64::from(value) > MAX_CHANNELS {
                return Err(RepresentError::Param {
                    name,
                    value: value.to_string(),
                    reason: "must be in 1..=4096",
                });
            }
        }
        self.stp_params().check()
    }
}

/// Computes representations of aligned windows. Holds TFSTP's synapses from window to window
/// (made at the first window that asks for `stp`, and again when the sensor size changes).
#[derive(Debug)]
pub struct Representer {
    cfg: RepresentConfig,
    stp: Option<StpFilter>,
}

impl Representer {
    /// A representer with checked settings.
    pub fn new(cfg: RepresentConfig) -> Result<Self, RepresentError> {
        cfg.check()?;
        Ok(Representer { cfg, stp: None })
    }

    /// The settings.
    pub fn config(&self) -> &RepresentConfig {
        &self.cfg
    }

    /// The representation `kind` of window `w`, stamped with the window's instant and sequence
    /// number. Only `stp` changes the representer's state: its synapses are fed the window's
    /// planes up to the reference plane, each plane once across windows.
    pub fn represent(
        &mut self,
        kind: RepresentationKind,
        w: &AlignedWindow,
    ) -> Result<Representation, RepresentError> {
        let (n, h, wd) = (w.spikes.n_planes, w.spikes.height, w.spikes.width);
        let c = w.ref_index();
        let mut params = BTreeMap::new();
        if let Some(g) = w.spikes.lum_per_rate {
            params.insert("lum_per_rate".to_string(), g);
        }
        let ev = &w.events;
        let events = EventSlice {
            t_ns: &ev.t_ns,
            x: &ev.x,
            y: &ev.y,
            polarity: &ev.polarity,
        };
        let (eh, ew) = (ev.height.max(1), ev.width.max(1));
        let data = match kind {
            RepresentationKind::Tfp => {
                let len = self.cfg.tfp_planes.map_or(n, |p| (p as usize).min(n));
                let start = c.saturating_sub(len / 2).min(n - len);
                params.insert("window".into(), len as f64);
                let mut dst = Array2::<f32>::zeros((h, wd));
                // Straight from the packed planes: no unpacking.
                tfp_packed_into(&w.spikes.bits, start..start + len, dst.view_mut())?;
                dst.insert_axis(Axis(0))
            }
            RepresentationKind::Isi => {
                let mut isi = Array2::<f32>::zeros((h, wd));
                let mut valid = Array2::<bool>::from_elem((h, wd), false);
                isi_packed_into(&w.spikes.bits, n, c, isi.view_mut(), valid.view_mut())?;
                let mut out = Array3::<f32>::zeros((2, h, wd));
                out.index_axis_mut(Axis(0), 0).assign(&isi);
                out.index_axis_mut(Axis(0), 1)
                    .assign(&valid.mapv(|v| f32::from(u8::from(v))));
                out
            }
            RepresentationKind::SpikeRepr => {
                let ch = self.cfg.repr_channels as usize;
                params.insert("channels".into(), ch as f64);
                let mut out = Array3::<f32>::zeros((ch, h, wd));
                spike_representation_packed_into(&w.spikes.bits, n, c, out.view_mut())?;
                out
            }
            RepresentationKind::EventIntegration => {
                let k = self.cfg.ei_channels as usize;
                let ts = integration_instants(ev.t_start_ns, ev.t_end_ns, k);
                params.insert("tau_ns".into(), self.cfg.tau_ns);
                let mut out = Array3::<f32>::zeros((k, eh, ew));
                event_integration_into(
                    events,
                    ev.t_start_ns,
                    &ts,
                    self.cfg.tau_ns,
                    out.view_mut(),
                )?;
                out
            }
            RepresentationKind::VoxelGrid => {
                let b = self.cfg.voxel_bins as usize;
                params.insert("bins".into(), b as f64);
                let mut out = Array3::<f32>::zeros((b, eh, ew));
                voxel_grid_into(events, VoxelNorm::NonZeroStandard, out.view_mut())?;
                out
            }
            RepresentationKind::EventStack => {
                let b = self.cfg.stack_bins as usize;
                params.insert("bins".into(), b as f64);
                let mut out = Array3::<f32>::zeros((b, eh, ew));
                event_stack_into(events, out.view_mut())?;
                out
            }
            RepresentationKind::TimeSurface => {
                params.insert("tau_ns".into(), self.cfg.surface_tau_ns);
                let mut out = Array3::<f32>::zeros((TIME_SURFACE_CHANNELS, eh, ew));
                time_surface_into(events, w.t_ref_ns, self.cfg.surface_tau_ns, out.view_mut())?;
                out
            }
            RepresentationKind::Stp => {
                let f = match &mut self.stp {
                    Some(f) if f.dim() == (h, wd) => f,
                    slot => slot.insert(StpFilter::new(h, wd, self.cfg.stp_params())?),
                };
                f.advance_packed(&w.spikes.bits, w.spikes.first_plane, n, w.ref_plane)?;
                params.insert("gaps".into(), f.gaps() as f64);
                let mut dst = Array2::<f32>::zeros((h, wd));
                f.rate_into(dst.view_mut())?;
                dst.insert_axis(Axis(0))
            }
        };
        Ok(Representation {
            kind,
            t_ref_ns: w.t_ref_ns,
            seq: w.seq(),
            params,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::{Event, EventBatch, SpikeChunk, pack_planes};

    /// A 4x3 window of 5 planes (pixel 0 firing at every plane) with events on both sides of its
    /// reference instant.
    fn window() -> AlignedWindow {
        let mut p = Array3::<u8>::zeros((5, 3, 4));
        p.slice_mut(ndarray::s![.., 0, 0]).fill(1);
        let spikes = SpikeChunk {
            width: 4,
            height: 3,
            first_plane: 10,
            n_planes: 5,
            t_first_ns: 100,
            plane_period_ns: 10,
            seq: 7,
            bits: pack_planes(p.view()),
            lum_per_rate: Some(1.0),
        };
        let mut events = EventBatch::empty(4, 3, 90, 140, 7);
        for (t_ns, x, y, polarity) in [
            (95, 1, 0, 1),
            (110, 2, 1, -1),
            (121, 1, 0, 1),
            (135, 3, 2, -1),
        ] {
            events.push(Event {
                t_ns,
                x,
                y,
                polarity,
            });
        }
        AlignedWindow {
            t_ref_ns: 120,
            ref_plane: 12,
            spikes,
            events,
        }
    }

    fn slice(b: &EventBatch) -> EventSlice<'_> {
        EventSlice {
            t_ns: &b.t_ns,
            x: &b.x,
            y: &b.y,
            polarity: &b.polarity,
        }
    }

    #[test]
    fn a_representation_of_too_many_channels_is_refused_before_anything_is_made() {
        let cfg = RepresentConfig {
            voxel_bins: u32::MAX,
            ..RepresentConfig::default()
        };
        let e = Representer::new(cfg).unwrap_err().to_string();
        assert!(e.contains("voxel-bins") && e.contains("4294967295"), "{e}");
        let cfg = RepresentConfig {
            ei_channels: 4096,
            ..RepresentConfig::default()
        };
        assert!(Representer::new(cfg).is_ok());
    }

    #[test]
    fn every_kind_is_its_kernel_on_the_window() {
        let w = window();
        let mut r = Representer::new(RepresentConfig {
            repr_channels: 4,
            voxel_bins: 3,
            stack_bins: 2,
            surface_tau_ns: 20.0,
            ..RepresentConfig::default()
        })
        .unwrap();
        for kind in RepresentationKind::ALL {
            let rep = r.represent(kind, &w).unwrap();
            assert_eq!((rep.kind, rep.seq, rep.t_ref_ns), (kind, 7, 120));
            assert_eq!((rep.data.dim().1, rep.data.dim().2), (3, 4), "{kind}");
        }
        let mut voxel = Array3::<f32>::zeros((3, 3, 4));
        voxel_grid_into(
            slice(&w.events),
            VoxelNorm::NonZeroStandard,
            voxel.view_mut(),
        )
        .unwrap();
        assert_eq!(
            r.represent(RepresentationKind::VoxelGrid, &w).unwrap().data,
            voxel
        );
        let mut stack = Array3::<f32>::zeros((2, 3, 4));
        event_stack_into(slice(&w.events), stack.view_mut()).unwrap();
        assert_eq!(
            r.represent(RepresentationKind::EventStack, &w)
                .unwrap()
                .data,
            stack
        );
        // The time surface at t_ref = 120: the ON event at 95 is 25 ns old, the OFF one at 110
        // 10 ns old; the events after t_ref do not count.
        let s = r
            .represent(RepresentationKind::TimeSurface, &w)
            .unwrap()
            .data;
        assert_eq!(s[[0, 0, 1]], (-25.0f64 / 20.0).exp() as f32);
        assert_eq!(s[[1, 1, 2]], (-10.0f64 / 20.0).exp() as f32);
        assert_eq!(s[[1, 2, 3]], 0.0);
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        for (cfg, name) in [
            (
                RepresentConfig {
                    tau_ns: -1.0,
                    ..RepresentConfig::default()
                },
                "tau-ns",
            ),
            (
                RepresentConfig {
                    surface_tau_ns: 0.0,
                    ..RepresentConfig::default()
                },
                "surface-tau-ns",
            ),
        ] {
            let e = Representer::new(cfg).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
    }
}
