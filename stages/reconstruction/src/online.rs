//! Every [`Method`] as one state machine fed window by window, in time order: what the `infer`
//! node runs. Each window brings what the method declares ([`Method::inputs`]): the spike
//! representation at `t_ref` (a firing-rate image or an ISI map with its validity) and the events
//! of `[previous t_ref, t_ref)` (the `align` node's event stream). The frame is the luminance at
//! `t_ref`.
//!
//! | method | spike input | events | frame |
//! |---|---|---|---|
//! | `tfp` | rate | - | [`luminance_from_rate_into`] |
//! | `tfi` | ISI | - | [`luminance_from_isi_into`] |
//! | `hf` | - | yes | [`HighPassFilter`] |
//! | `cf` | rate or ISI, as luminance | yes | [`ComplementaryFilter`] fed the TFP or TFI frame |
//! | `fusion` | ISI | yes | [`PhysicsFusion`] (Eq. 5-7) |
//! | `fusion` | rate | yes | [`RateFusion`]: a recursive log estimate each window's count corrects and the events carry (Eq. 5) |

use ndarray::{Array2, ArrayView2, ArrayViewMut2};
use neuspike_schemas::RepresentationKind;

use crate::recursive::{RateFusion, RateFusionParams};
use crate::{
    ComplementaryFilter, Contrast, EventSlice, FusionFrameStats, FusionParams, HighPassFilter,
    InferError, IsiUpdateStats, Method, PhysicsFusion, ThetaMode, luminance_from_isi_into,
    luminance_from_rate_into,
};

/// What a method reads from each window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodInputs {
    /// The representation kinds it accepts; empty when it needs none (or, for
    /// [`Method::Learned`], when its model says).
    pub representations: &'static [RepresentationKind],
    /// Whether it needs the event stream.
    pub events: bool,
}

/// Settings of the event-driven methods; every field is a node argument.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OnlineParams {
    /// The DVS contrast threshold (log luminance per event) HF and CF step by.
    pub contrast: f64,
    /// HF cutoff, rad/s.
    pub hf_cutoff_rad_s: f64,
    /// CF gain (how fast the spike frames pull the estimate), rad/s.
    pub cf_gain_rad_s: f64,
    /// Fusion: where theta comes from, and its value before any estimate.
    pub theta_mode: ThetaMode,
    /// Fusion: theta before any estimate.
    pub theta_init: f64,
    /// Fusion and CF: take the spike input of one window in this many (at least 1); between two,
    /// the estimate is carried forward by the events alone (Eq. 7 for the fusion). The spike side
    /// then needs computing only every N windows: the dial between speed and accuracy.
    pub anchor_every: u32,
}

impl Default for OnlineParams {
    fn default() -> Self {
        OnlineParams {
            contrast: 0.2,
            hf_cutoff_rad_s: 5.0,
            cf_gain_rad_s: 5.0,
            theta_mode: ThetaMode::Global,
            theta_init: 0.2,
            anchor_every: 1,
        }
    }
}

/// The spike side of one window.
#[derive(Clone, Copy, Debug)]
pub enum SpikeInput<'a> {
    /// A firing-rate image (spikes per tick, TFP).
    Rate(ArrayView2<'a, f32>),
    /// A firing-rate image (spikes per tick) from short-term plasticity (represent's `stp`).
    StpRate(ArrayView2<'a, f32>),
    /// An ISI map in ticks and its validity (`> 0.5` valid, as the `represent` node writes it).
    Isi {
        /// Interval at `t_ref`, ticks.
        isi: ArrayView2<'a, f32>,
        /// 1 where the interval was measured, 0 where it is a bound.
        valid: ArrayView2<'a, f32>,
    },
}

impl SpikeInput<'_> {
    fn kind(&self) -> RepresentationKind {
        match self {
            SpikeInput::Rate(_) => RepresentationKind::Tfp,
            SpikeInput::StpRate(_) => RepresentationKind::Stp,
            SpikeInput::Isi { .. } => RepresentationKind::Isi,
        }
    }

    fn dim(&self) -> (usize, usize) {
        match self {
            SpikeInput::Rate(r) | SpikeInput::StpRate(r) => r.dim(),
            SpikeInput::Isi { isi, .. } => isi.dim(),
        }
    }

    /// The spike camera's luminance: TFP or TFI.
    fn luminance_into(&self, gain: f64, dst: ArrayViewMut2<f32>) -> Result<(), InferError> {
        match self {
            SpikeInput::Rate(r) | SpikeInput::StpRate(r) => {
                luminance_from_rate_into(*r, gain, 1.0, dst)
            }
            SpikeInput::Isi { isi, .. } => luminance_from_isi_into(*isi, gain, 1.0, dst),
        }
    }
}

/// One window's inputs.
#[derive(Clone, Copy, Debug)]
pub struct Window<'a> {
    /// The reconstruction instant.
    pub t_ref_ns: i64,
    /// The spike representation at `t_ref`, if the method takes one.
    pub spikes: Option<SpikeInput<'a>>,
    /// Luminance per unit firing rate (`phi / light_scale`), needed with `spikes`.
    pub lum_per_rate: Option<f64>,
    /// The events of `[previous t_ref, t_ref)` and the sensor size `(height, width)` they are
    /// on, if the method takes them.
    pub events: Option<(EventSlice<'a>, (usize, usize))>,
    /// The planes a rate was measured over (its representation's `window`): the fusion turns a
    /// rate back into a spike count. `None` reads as 33 (align's default window).
    pub planes: Option<usize>,
}

/// Counts over a run, for the node's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OnlineStats {
    /// Frames produced.
    pub frames: u64,
    /// Events applied.
    pub events: u64,
    /// Fusion: the ISI updates, summed.
    pub isi: IsiUpdateStats,
    /// Fusion: the frames' pixels, summed (clamps and `exp` overflows included).
    pub frame: FusionFrameStats,
}

enum State {
    Direct,
    Hf(HighPassFilter),
    Cf(ComplementaryFilter, Array2<f32>),
    Fusion(PhysicsFusion, Array2<bool>),
    RateFusion(RateFusion),
}

/// A method's state across windows. The sensor size is taken from the first window.
pub struct Online {
    method: Method,
    params: OnlineParams,
    state: Option<State>,
    dim: (usize, usize),
    stats: OnlineStats,
    /// Windows seen, for `anchor_every`.
    windows: u64,
}

impl Method {
    /// What the method reads from each window.
    pub fn inputs(&self) -> MethodInputs {
        use RepresentationKind::{Isi, Stp, Tfp};
        let (representations, events): (&'static [RepresentationKind], bool) = match self {
            Method::Tfp => (&[Tfp], false),
            Method::Tfi => (&[Isi], false),
            Method::Tfstp => (&[Stp], false),
            Method::Hf => (&[], true),
            Method::Cf => (&[Tfp, Isi], true),
            Method::Fusion => (&[Isi, Tfp], true),
            Method::Learned | Method::Auto => (&[], false),
        };
        MethodInputs {
            representations,
            events,
        }
    }
}

impl Method {
    /// The representation a graph gives the method on its `representation` input (the TFI
    /// frames for `cf`, which takes TFP too), if it reads one; the learned method reads what its
    /// model names.
    pub fn graph_representation(self) -> Option<RepresentationKind> {
        match self {
            Method::Tfp => Some(RepresentationKind::Tfp),
            Method::Tfstp => Some(RepresentationKind::Stp),
            Method::Tfi | Method::Cf | Method::Fusion => Some(RepresentationKind::Isi),
            Method::Hf | Method::Learned | Method::Auto => None,
        }
    }
}

impl Online {
    /// A method with its settings; nothing is allocated before the first window.
    ///
    /// # Errors
    /// [`InferError::Param`] naming a setting out of its domain.
    pub fn new(method: Method, params: OnlineParams) -> Result<Self, InferError> {
        let bad = |name, value, reason| {
            Err(InferError::Param {
                name,
                value,
                reason,
            })
        };
        if method.inputs().events {
            Contrast::symmetric(params.contrast).check()?;
            for (name, v) in [
                ("hf-cutoff-rad-s", params.hf_cutoff_rad_s),
                ("cf-gain-rad-s", params.cf_gain_rad_s),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return bad(name, v, "must be finite and >= 0");
                }
            }
        }
        if method == Method::Learned {
            return Err(InferError::NeedsModel);
        }
        if method == Method::Auto {
            return Err(InferError::Wiring(
                "method `auto` chooses per window: the infer stage runs it (`InferConfig::reconstructor`)".into(),
            ));
        }
        if params.anchor_every == 0 {
            return bad("anchor-every", 0.0, "must be >= 1");
        }
        if method == Method::Fusion {
            let mut p = FusionParams::new(1.0, 1.0);
            p.theta_init = params.theta_init;
            p.mode = params.theta_mode;
            PhysicsFusion::new(1, 1, p, 0)?;
        }
        Ok(Online {
            method,
            params,
            state: None,
            dim: (0, 0),
            stats: OnlineStats::default(),
            windows: 0,
        })
    }

    /// The counts so far.
    pub fn stats(&self) -> OnlineStats {
        self.stats
    }

    /// The frame at the window's `t_ref`, `[H, W]` luminance in `[0, 1]`.
    ///
    /// # Errors
    /// - [`InferError::Missing`] when the window lacks what the method reads, or a spike input of
    ///   the wrong kind;
    /// - [`InferError::Shape`] when the spike and event sensors differ, or either differs from the
    ///   first window's;
    /// - whatever the method's own checks refuse (events out of order or outside the sensor, time
    ///   going backwards), with nothing applied.
    pub fn frame(&mut self, w: &Window<'_>) -> Result<Array2<f32>, InferError> {
        let needs = self.method.inputs();
        let spikes = match (needs.representations.is_empty(), w.spikes) {
            (true, _) => None,
            (false, Some(s)) if needs.representations.contains(&s.kind()) => Some(s),
            (false, other) => {
                return Err(InferError::Missing {
                    method: self.method.as_str(),
                    what: format!(
                        "the `{}` representation, got {}",
                        needs
                            .representations
                            .iter()
                            .map(|k| k.name())
                            .collect::<Vec<_>>()
                            .join("` or `"),
                        other.map_or("none".to_string(), |s| format!("`{}`", s.kind()))
                    ),
                });
            }
        };
        let gain = match (spikes, w.lum_per_rate) {
            (None, _) => 1.0,
            (Some(_), Some(g)) => g,
            (Some(_), None) => {
                return Err(InferError::Missing {
                    method: self.method.as_str(),
                    what: "a calibration (`lum_per_rate`)".into(),
                });
            }
        };
        let events = match (needs.events, w.events) {
            (false, _) => None,
            (true, Some(e)) => Some(e),
            (true, None) => {
                return Err(InferError::Missing {
                    method: self.method.as_str(),
                    what: "the event stream (connect align's `events` output)".into(),
                });
            }
        };
        let dim = match (spikes, events) {
            (Some(s), Some((_, d))) if s.dim() != d => {
                return Err(InferError::Shape {
                    what: "event sensor (must be the spike camera's size: set the event source's --width/--height)",
                    expected: [s.dim().0, s.dim().1],
                    actual: [d.0, d.1],
                });
            }
            (Some(s), _) => s.dim(),
            (None, Some((_, d))) => d,
            (None, None) => (0, 0),
        };
        if self.state.is_none() {
            self.start(dim, w, events.map(|(e, _)| e))?;
        } else if dim != self.dim {
            return Err(InferError::Shape {
                what: "window (the sensor size changed)",
                expected: [self.dim.0, self.dim.1],
                actual: [dim.0, dim.1],
            });
        }
        let mut dst = Array2::<f32>::zeros(dim);
        let t = w.t_ref_ns;
        let anchor = self
            .windows
            .is_multiple_of(u64::from(self.params.anchor_every));
        self.windows += 1;
        match (self.state.as_mut(), spikes, events) {
            (Some(State::Direct), Some(s), _) => s.luminance_into(gain, dst.view_mut())?,
            (Some(State::Hf(hf)), _, Some((e, _))) => {
                hf.push_events(e, Contrast::symmetric(self.params.contrast))?;
                hf.frame_into(t, dst.view_mut())?;
            }
            (Some(State::Cf(cf, lum)), Some(s), Some((e, _))) => {
                cf.push_events(e, Contrast::symmetric(self.params.contrast))?;
                if anchor {
                    s.luminance_into(gain, lum.view_mut())?;
                    cf.push_frame(t, lum.view())?;
                }
                cf.frame_into(t, dst.view_mut())?;
            }
            (
                Some(State::Fusion(f, valid)),
                Some(SpikeInput::Isi { isi, valid: v }),
                Some((e, _)),
            ) => {
                f.push_events(e)?;
                if anchor {
                    let mask = v.mapv(|x| x > 0.5);
                    self.stats.isi += f.push_isi(t, isi, mask.view())?;
                }
                let s = f.frame_into(t, dst.view_mut(), valid.view_mut())?;
                self.stats.frame += s;
            }
            (Some(State::RateFusion(f)), Some(SpikeInput::Rate(r)), Some((e, _))) => {
                f.push_events(e)?;
                if anchor {
                    f.push_rate(t, r, w.planes.unwrap_or(33))?;
                }
                f.frame_into(t, dst.view_mut())?;
            }
            (Some(State::Fusion(..) | State::RateFusion(_)), Some(s), _) => {
                return Err(InferError::Missing {
                    method: self.method.as_str(),
                    what: format!(
                        "the representation its first window brought (`isi` or `tfp`, not both), got `{}`",
                        s.kind()
                    ),
                });
            }
            _ => unreachable!("inputs checked against the method above"),
        }
        self.stats.frames += 1;
        self.stats.events += events.map_or(0, |(e, _)| e.len() as u64);
        Ok(dst)
    }

    /// Builds the method's state for the first window.
    fn start(
        &mut self,
        (h, w): (usize, usize),
        win: &Window<'_>,
        events: Option<EventSlice<'_>>,
    ) -> Result<(), InferError> {
        // The filters start just before the first event they will see (or at t_ref).
        let t0 = events
            .and_then(|e| e.t_ns.first().copied())
            .unwrap_or(win.t_ref_ns)
            .min(win.t_ref_ns);
        let p = self.params;
        self.state = Some(match self.method {
            Method::Tfp | Method::Tfi | Method::Tfstp => State::Direct,
            Method::Learned | Method::Auto => return Err(InferError::NeedsModel),
            Method::Hf => State::Hf(HighPassFilter::new(h, w, p.hf_cutoff_rad_s, t0)?),
            Method::Cf => State::Cf(
                ComplementaryFilter::new(h, w, p.cf_gain_rad_s, t0)?,
                Array2::zeros((h, w)),
            ),
            Method::Fusion if matches!(win.spikes, Some(SpikeInput::Rate(_))) => {
                let rp = RateFusionParams::new(win.lum_per_rate.unwrap_or(1.0), p.contrast);
                State::RateFusion(RateFusion::new(h, w, rp, t0)?)
            }
            Method::Fusion => {
                let mut fp = FusionParams::new(win.lum_per_rate.unwrap_or(1.0), 1.0);
                fp.theta_init = p.theta_init;
                fp.mode = p.theta_mode;
                State::Fusion(
                    PhysicsFusion::new(h, w, fp, t0)?,
                    Array2::from_elem((h, w), false),
                )
            }
        });
        self.dim = (h, w);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, array};

    const T: [i64; 3] = [100, 150, 199];
    const X: [u16; 3] = [0, 1, 1];
    const Y: [u16; 3] = [0, 0, 1];
    const P: [i8; 3] = [1, -1, 1];

    fn events(from: usize) -> EventSlice<'static> {
        EventSlice {
            t_ns: &T[from..],
            x: &X[from..],
            y: &Y[from..],
            polarity: &P[from..],
        }
    }

    /// The state machine gives exactly what the filter gives when driven by hand.
    #[test]
    fn cf_equals_the_filter_driven_by_hand() {
        let rate = array![[0.25f32, 0.5], [0.125, 1.0]];
        let mut online = Online::new(Method::Cf, OnlineParams::default()).unwrap();
        let mut cf = ComplementaryFilter::new(2, 2, 5.0, 100).unwrap();
        let mut lum = Array2::<f32>::zeros((2, 2));
        for (k, (t_ref, from, to)) in [(120, 0, 1), (200, 1, 3)].into_iter().enumerate() {
            let e = EventSlice {
                t_ns: &T[from..to],
                x: &X[from..to],
                y: &Y[from..to],
                polarity: &P[from..to],
            };
            let w = Window {
                t_ref_ns: t_ref,
                spikes: Some(SpikeInput::Rate(rate.view())),
                lum_per_rate: Some(2.0),
                events: Some((e, (2, 2))),
                planes: None,
            };
            let got = online.frame(&w).unwrap();
            cf.push_events(e, Contrast::symmetric(0.2)).unwrap();
            luminance_from_rate_into(rate.view(), 2.0, 1.0, lum.view_mut()).unwrap();
            cf.push_frame(t_ref, lum.view()).unwrap();
            let mut want = Array2::<f32>::zeros((2, 2));
            cf.frame_into(t_ref, want.view_mut()).unwrap();
            assert_eq!(got, want, "window {k}");
        }
        assert_eq!(online.stats().frames, 2);
        assert_eq!(online.stats().events, 3);
    }

    /// With `anchor_every` 2 the second window's ISI is not used: the fusion carries the first
    /// anchor forward by the events in between (Eq. 7), where every window re-anchored gives
    /// the new ISI's luminance.
    #[test]
    fn fusion_carries_the_anchor_forward_between_anchors() {
        let valid = Array2::<f32>::ones((1, 1));
        let (isi_a, isi_b) = (array![[8.0f32]], array![[2.0f32]]);
        let on = [1i8; 3];
        let (t, x) = ([150i64, 160, 170], [0u16; 3]);
        let frames = |anchor_every| {
            let p = OnlineParams {
                anchor_every,
                theta_mode: ThetaMode::Fixed,
                theta_init: 0.2,
                ..OnlineParams::default()
            };
            let mut o = Online::new(Method::Fusion, p).unwrap();
            let none = EventSlice {
                t_ns: &[],
                x: &[],
                y: &[],
                polarity: &[],
            };
            let mut out = Vec::new();
            for (t_ref, isi, e) in [
                (100, &isi_a, none),
                (
                    200,
                    &isi_b,
                    EventSlice {
                        t_ns: &t,
                        x: &x,
                        y: &x,
                        polarity: &on,
                    },
                ),
            ] {
                let w = Window {
                    t_ref_ns: t_ref,
                    spikes: Some(SpikeInput::Isi {
                        isi: isi.view(),
                        valid: valid.view(),
                    }),
                    lum_per_rate: Some(1.0),
                    events: Some((e, (1, 1))),
                    planes: None,
                };
                out.push(o.frame(&w).unwrap()[[0, 0]]);
            }
            out
        };
        let every = frames(1);
        assert_eq!(every, vec![1.0 / 8.0, 1.0 / 2.0]);
        let carried = frames(2);
        assert_eq!(carried[0], 1.0 / 8.0);
        let want = (1.0f64 / 8.0 * (0.2f64 * 3.0).exp()) as f32;
        assert!((carried[1] - want).abs() < 1e-6, "{carried:?} vs {want}");
        let e = Online::new(
            Method::Fusion,
            OnlineParams {
                anchor_every: 0,
                ..OnlineParams::default()
            },
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("anchor-every"), "{e}");
    }

    #[test]
    fn missing_inputs_and_other_sizes_are_named() {
        let isi = Array2::<f32>::from_elem((2, 2), 4.0);
        let valid = Array2::<f32>::ones((2, 2));
        let spikes = SpikeInput::Isi {
            isi: isi.view(),
            valid: valid.view(),
        };
        let mut f = Online::new(Method::Fusion, OnlineParams::default()).unwrap();
        let no_events = Window {
            t_ref_ns: 200,
            spikes: Some(spikes),
            lum_per_rate: Some(1.0),
            events: None,
            planes: None,
        };
        let e = f.frame(&no_events).unwrap_err().to_string();
        assert!(e.contains("`fusion` needs the event stream"), "{e}");
        let other_size = Window {
            events: Some((events(0), (3, 2))),
            planes: None,
            ..no_events
        };
        let e = f.frame(&other_size).unwrap_err().to_string();
        assert!(e.contains("event sensor") && e.contains("[3, 2]"), "{e}");
        let rate = Array2::<f32>::zeros((2, 2));
        let wrong_kind = Window {
            spikes: Some(SpikeInput::StpRate(rate.view())),
            events: Some((events(0), (2, 2))),
            planes: None,
            ..no_events
        };
        let e = f.frame(&wrong_kind).unwrap_err().to_string();
        assert!(
            e.contains("the `isi` or `tfp` representation, got `stp`"),
            "{e}"
        );
        let uncalibrated = Window {
            lum_per_rate: None,
            events: Some((events(0), (2, 2))),
            planes: None,
            ..no_events
        };
        let e = f.frame(&uncalibrated).unwrap_err().to_string();
        assert!(e.contains("lum_per_rate"), "{e}");
        let e = Online::new(
            Method::Hf,
            OnlineParams {
                hf_cutoff_rad_s: f64::NAN,
                ..OnlineParams::default()
            },
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("hf-cutoff-rad-s"), "{e}");
    }

    /// Every frame is finite and in [0, 1], whatever the method, with a flood of one polarity.
    #[test]
    fn frames_stay_finite_under_a_flood() {
        let n = 100_000;
        let t: Vec<i64> = (0..n as i64).map(|k| 1_000 + k).collect();
        let zeros = vec![0u16; n];
        let ons = vec![1i8; n];
        let flood = EventSlice {
            t_ns: &t,
            x: &zeros,
            y: &zeros,
            polarity: &ons,
        };
        let isi = Array2::<f32>::from_elem((1, 1), 4.0);
        let valid = Array2::<f32>::ones((1, 1));
        for m in [Method::Hf, Method::Cf, Method::Fusion] {
            let mut o = Online::new(m, OnlineParams::default()).unwrap();
            let w = Window {
                t_ref_ns: 1_000 + n as i64,
                spikes: Some(SpikeInput::Isi {
                    isi: isi.view(),
                    valid: valid.view(),
                }),
                lum_per_rate: Some(1.0),
                events: Some((flood, (1, 1))),
                planes: None,
            };
            let f = o.frame(&w).unwrap();
            assert!(
                f.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                "{m}: {f:?}"
            );
        }
    }
}
