//! dora node: reconstruction. Inputs, as the method declares ([`Method::inputs`]):
//! `representation` (Representation: `tfp` or `isi`) and `events` (EventBatch: the `align` node's
//! event stream, cut at each window's `t_ref`). Output `frames` (Frame). Methods: `tfp` (needs
//! `tfp`), `tfi` (needs `isi`), `hf` (events), `cf` (events and `tfp` or `isi`), `fusion` (events
//! and `isi`). The two inputs of one window carry the window's sequence number; a window is
//! reconstructed when both have arrived, in order.

use std::collections::BTreeMap;
use std::time::Instant;

use dora_node_api::{DoraNode, Event, EventStream};
use ndarray::Axis;
use neuspike_infer::{EventSlice, Method, Online, OnlineParams, SpikeInput, ThetaMode, Window};
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{
    EventBatch, Frame, FrameKind, Message, Representation, SeqStatus, SeqTracker, is_end_of_stream,
};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-infer",
    about = "Reconstructs frames from representations and events",
    args_override_self = true
)]
struct Args {
    /// Reconstruction method: tfp, tfi, hf, cf or fusion.
    #[arg(long, default_value = "tfp")]
    method: Method,
    /// Luminance per unit firing rate (overrides the calibration the spike source sends).
    #[arg(long)]
    lum_per_rate: Option<f64>,
    /// hf, cf: the DVS contrast threshold (log luminance per event).
    #[arg(long, default_value_t = 0.2)]
    contrast: f64,
    /// hf: cutoff of the high-pass filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    hf_cutoff_rad_s: f64,
    /// cf: gain of the complementary filter, rad/s.
    #[arg(long, default_value_t = 5.0)]
    cf_gain_rad_s: f64,
    /// fusion: where theta comes from: fixed, global or per-pixel.
    #[arg(long, default_value = "global", value_parser = parse_theta_mode)]
    theta_mode: ThetaMode,
    /// fusion: theta before any estimate.
    #[arg(long, default_value_t = 0.2)]
    theta_init: f64,
    /// cf, fusion: use the spike input of one window in this many; events carry the estimate in
    /// between.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    anchor_every: u32,
}

fn parse_theta_mode(s: &str) -> Result<ThetaMode, String> {
    match s {
        "fixed" => Ok(ThetaMode::Fixed),
        "global" => Ok(ThetaMode::Global),
        "per-pixel" => Ok(ThetaMode::PerPixel),
        _ => Err(format!("{s:?} is not one of fixed, global, per-pixel")),
    }
}

impl Args {
    fn online(&self) -> OnlineParams {
        OnlineParams {
            contrast: self.contrast,
            hf_cutoff_rad_s: self.hf_cutoff_rad_s,
            cf_gain_rad_s: self.cf_gain_rad_s,
            theta_mode: self.theta_mode,
            theta_init: self.theta_init,
            anchor_every: self.anchor_every,
        }
    }

    /// Checks the settings and that the graph connects what the method reads.
    fn check(&self, inputs: &[String]) -> eyre::Result<()> {
        if let Some(g) = self.lum_per_rate
            && !(g.is_finite() && g > 0.0)
        {
            eyre::bail!("infer: `lum-per-rate` = {g} is invalid: must be finite and > 0");
        }
        Online::new(self.method, self.online()).map_err(|e| eyre::eyre!("infer: {e}"))?;
        let needs = self.method.inputs();
        let has = |id: &str| inputs.iter().any(|i| i == id);
        if !needs.representations.is_empty() && !has("representation") {
            eyre::bail!(
                "infer: method `{}` needs an input `representation` ({} from the represent node)",
                self.method,
                needs.representations.join(" or ")
            );
        }
        if needs.events && !has("events") {
            eyre::bail!(
                "infer: method `{}` needs an input `events` (the align node's `events` output)",
                self.method
            );
        }
        Ok(())
    }
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("infer")?;
    let (node, events) = DoraNode::init_from_env()?;
    let inputs: Vec<String> = node
        .node_config()
        .inputs
        .keys()
        .map(|k| k.to_string())
        .collect();
    args.check(&inputs)?;
    node::run_on_rayon("infer", || run(node, events, &args))
}

/// The inputs of one window gathered so far.
#[derive(Default)]
struct Pending {
    representation: Option<Representation>,
    events: Option<EventBatch>,
}

/// One input's stream state.
#[derive(Default)]
struct Input {
    seq: SeqTracker,
    ended: bool,
}

impl Input {
    fn observe(&mut self, name: &str, seq: u64) {
        if let SeqStatus::Gap { missing } = self.seq.observe(seq) {
            tracing::error!(input = name, seq, missing, "messages lost before this one");
        }
    }
}

struct Reconstructor {
    online: Online,
    args_lum_per_rate: Option<f64>,
    method: Method,
    wants_rep: bool,
    wants_events: bool,
    pending: BTreeMap<u64, Pending>,
    frames: u64,
    incomplete: u64,
}

impl Reconstructor {
    fn complete(&self, p: &Pending) -> bool {
        (!self.wants_rep || p.representation.is_some())
            && (!self.wants_events || p.events.is_some())
    }

    /// Reconstructs every window whose inputs are all in, in order. A window that is still
    /// incomplete when a later one is complete lost a message (inputs arrive in order): it is
    /// dropped and counted.
    fn drain(&mut self, node: &mut DoraNode, flush: bool) -> eyre::Result<()> {
        let done: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| self.complete(p))
            .map(|(&k, _)| k)
            .collect();
        let Some(&last_done) = done.last() else {
            if flush {
                self.incomplete += self.pending.len() as u64;
                self.pending.clear();
            }
            return Ok(());
        };
        let limit = if flush { u64::MAX } else { last_done };
        while let Some(entry) = self.pending.first_entry() {
            if *entry.key() > limit {
                break;
            }
            let (seq, p) = entry.remove_entry();
            if !self.complete(&p) {
                tracing::error!(seq, "window incomplete (a message was lost): no frame");
                self.incomplete += 1;
                continue;
            }
            self.reconstruct(node, seq, &p)?;
        }
        Ok(())
    }

    fn reconstruct(&mut self, node: &mut DoraNode, seq: u64, p: &Pending) -> eyre::Result<()> {
        let start = Instant::now();
        let rep = p.representation.as_ref();
        let spikes = rep.map(|r| -> eyre::Result<SpikeInput<'_>> {
            Ok(match r.kind.as_str() {
                "tfp" => SpikeInput::Rate(r.data.index_axis(Axis(0), 0)),
                "isi" if r.data.dim().0 >= 2 => SpikeInput::Isi {
                    isi: r.data.index_axis(Axis(0), 0),
                    valid: r.data.index_axis(Axis(0), 1),
                },
                other => eyre::bail!(
                    "infer: method `{}` cannot use the `{other}` representation (seq {seq}); it takes {}",
                    self.method,
                    self.method.inputs().representations.join(" or ")
                ),
            })
        });
        let spikes = spikes.transpose()?;
        let lum_per_rate = self
            .args_lum_per_rate
            .or_else(|| rep.and_then(|r| r.params.get("lum_per_rate").copied()));
        let events = p.events.as_ref().map(|b| {
            (
                EventSlice {
                    t_ns: &b.t_ns,
                    x: &b.x,
                    y: &b.y,
                    polarity: &b.polarity,
                },
                (b.height, b.width),
            )
        });
        let t_ref_ns = match (rep, &p.events) {
            (Some(r), _) => r.t_ref_ns,
            (None, Some(b)) => b.t_end_ns,
            (None, None) => eyre::bail!("infer: window {seq} has no input"),
        };
        if let (Some(r), Some(b)) = (rep, &p.events)
            && b.t_end_ns != r.t_ref_ns
        {
            eyre::bail!(
                "infer: window {seq}: the event batch ends at {} ns but the representation is at t_ref {} ns (connect align's `events` output, which cuts the stream at each t_ref)",
                b.t_end_ns,
                r.t_ref_ns
            );
        }
        let window = Window {
            t_ref_ns,
            spikes,
            lum_per_rate,
            events,
        };
        let data = self.online.frame(&window).map_err(|e| {
            let hint = if lum_per_rate.is_none() && spikes.is_some() {
                " (the representation carries no `lum_per_rate` and the graph sets no `--lum-per-rate`)"
            } else {
                ""
            };
            eyre::eyre!("infer: window {seq} at {t_ref_ns} ns: {e}{hint}")
        })?;
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: self.method.to_string(),
            t_ref_ns,
            compute_ns: i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX),
            seq,
            data,
        };
        send(node, &output("frames"), &frame)?;
        self.frames = seq + 1;
        Ok(())
    }
}

fn run(mut node: DoraNode, mut events: EventStream, args: &Args) -> eyre::Result<()> {
    let needs = args.method.inputs();
    let mut r = Reconstructor {
        online: Online::new(args.method, args.online())?,
        args_lum_per_rate: args.lum_per_rate,
        method: args.method,
        wants_rep: !needs.representations.is_empty(),
        wants_events: needs.events,
        pending: BTreeMap::new(),
        frames: 0,
        incomplete: 0,
    };
    let (mut rep_in, mut ev_in) = (Input::default(), Input::default());
    let mut announced = 0u64;
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } => {
                let meta = &metadata.parameters;
                let id: &str = id.as_ref();
                let (input, wanted) = match id {
                    "representation" => (&mut rep_in, r.wants_rep),
                    "events" => (&mut ev_in, r.wants_events),
                    other => {
                        tracing::warn!(input = other, "unknown input ignored");
                        continue;
                    }
                };
                if !wanted {
                    tracing::warn!(input = id, method = %args.method, "input not used by the method");
                    continue;
                }
                if let Some(n) = is_end_of_stream(meta) {
                    let lost = input.seq.end(n);
                    if lost > 0 {
                        tracing::error!(input = id, lost, "messages lost at the end of the stream");
                    }
                    input.ended = true;
                    announced = announced.max(n);
                } else if id == "representation" {
                    let rep = Representation::from_arrow(meta, data.as_array())?;
                    let seq = rep.seq;
                    input.observe(id, seq);
                    r.pending.entry(seq).or_default().representation = Some(rep);
                } else {
                    let batch = EventBatch::from_arrow(meta, data.as_array())?;
                    let seq = batch.seq;
                    input.observe(id, seq);
                    r.pending.entry(seq).or_default().events = Some(batch);
                }
                r.drain(&mut node, false)?;
                if (!r.wants_rep || rep_in.ended) && (!r.wants_events || ev_in.ended) {
                    break;
                }
            }
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs: only the
            // end-of-stream markers, or the end of the event stream, end the loop.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the input"),
            _ => {}
        }
    }
    r.drain(&mut node, true)?;
    let count = r.frames.max(announced);
    send_end::<Frame>(&mut node, &output("frames"), count)?;
    let s = r.online.stats();
    tracing::info!(
        frames = s.frames,
        announced = count,
        incomplete = r.incomplete,
        lost = rep_in.seq.missing() + ev_in.seq.missing(),
        events = s.events,
        method = %args.method,
        clamped = s.frame.clamped,
        exp_overflow = s.frame.exp_overflow,
        "infer finished"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use neuspike_schemas::testing::{CannedInputs, output_ids};

    fn rep(kind: &str, value: f32, seq: u64) -> Representation {
        let mut data = Array3::from_elem((if kind == "isi" { 2 } else { 1 }, 3, 4), value);
        if kind == "isi" {
            data.index_axis_mut(Axis(0), 1).fill(1.0); // every ISI measured
        }
        Representation {
            kind: kind.into(),
            t_ref_ns: 1_000_000 * (seq as i64 + 1),
            seq,
            params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
            data,
        }
    }

    /// The event stream's batch of window `seq`: `[seq ms, seq + 1 ms)`, with `n` ON events at
    /// pixel (1, 2).
    fn batch(seq: u64, n: usize, (h, w): (usize, usize)) -> EventBatch {
        let t0 = 1_000_000 * seq as i64;
        let mut b = EventBatch::empty(w, h, t0, t0 + 1_000_000, seq);
        for k in 0..n {
            b.push(neuspike_schemas::Event {
                t_ns: t0 + 1_000 * k as i64,
                x: 1,
                y: 2,
                polarity: 1,
            });
        }
        b
    }

    fn args(method: Method) -> Args {
        Args {
            method,
            lum_per_rate: None,
            contrast: 0.2,
            hf_cutoff_rad_s: 5.0,
            cf_gain_rad_s: 5.0,
            theta_mode: ThetaMode::Global,
            theta_init: 0.2,
            anchor_every: 1,
        }
    }

    fn values(frame: &neuspike_schemas::testing::OutputJson) -> Vec<f64> {
        frame["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    }

    #[test]
    fn tfp_frames_use_the_calibration() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        c.message("representation", &rep("tfp", 0.25, 1)).unwrap();
        c.end::<Representation>("representation", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Tfp)))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let v = values(&out[0]);
        assert_eq!(v.len(), 12);
        assert!(v.iter().all(|v| (v - 0.5).abs() < 1e-6), "{v:?}");
    }

    #[test]
    fn wrong_representation_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        let err = c
            .run(|node, events| run(node, events, &args(Method::Tfi)))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`tfi` needs the `isi`") && err.contains("got `tfp`"),
            "{err}"
        );
    }

    #[test]
    fn hf_reconstructs_from_the_event_stream_alone() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (3, 4))).unwrap();
        c.message("events", &batch(1, 3, (3, 4))).unwrap();
        c.end::<EventBatch>("events", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Hf)))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let (first, second) = (values(&out[0]), values(&out[1]));
        // No events: every pixel at rest. Three ON events at (x 1, y 2): brighter there only.
        assert!(first.iter().all(|&v| v == first[0]), "{first:?}");
        let hit = 2 * 4 + 1;
        assert!(second[hit] > first[hit] * 1.5, "{second:?}");
        assert!(
            second
                .iter()
                .enumerate()
                .all(|(i, &v)| i == hit || v == first[0])
        );
    }

    #[test]
    fn fusion_pairs_windows_by_sequence_whatever_the_arrival_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (3, 4))).unwrap();
        c.message("events", &batch(1, 2, (3, 4))).unwrap();
        c.message("representation", &rep("isi", 8.0, 0)).unwrap();
        c.end::<EventBatch>("events", 2).unwrap();
        // Window 1's ISI says invalid nowhere but is a bound-free measurement of the same light:
        // the anchor is re-measured; the two events in between count into theta's estimate.
        c.message("representation", &rep("isi", 8.0, 1)).unwrap();
        c.end::<Representation>("representation", 2).unwrap();
        let out = c
            .run(|node, events| run(node, events, &args(Method::Fusion)))
            .unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        for f in &out[..2] {
            let v = values(f);
            // TFI of an 8-tick ISI at lum_per_rate 2: 0.25.
            assert!(v.iter().all(|v| (v - 0.25).abs() < 1e-6), "{v:?}");
        }
    }

    #[test]
    fn event_sensor_of_another_size_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("events", &batch(0, 0, (260, 346))).unwrap();
        c.message("representation", &rep("isi", 8.0, 0)).unwrap();
        let err = c
            .run(|node, events| run(node, events, &args(Method::Fusion)))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("event sensor") && err.contains("[260, 346]"),
            "{err}"
        );
    }

    #[test]
    fn a_graph_without_the_inputs_a_method_reads_is_refused_at_start_up() {
        let only_rep = ["representation".to_string()];
        let err = args(Method::Fusion)
            .check(&only_rep)
            .unwrap_err()
            .to_string();
        assert!(err.contains("`fusion` needs an input `events`"), "{err}");
        let only_events = ["events".to_string()];
        let err = args(Method::Cf)
            .check(&only_events)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`representation`") && err.contains("tfp or isi"),
            "{err}"
        );
        assert!(args(Method::Hf).check(&only_events).is_ok());
        let mut bad = args(Method::Hf);
        bad.contrast = -1.0;
        let err = bad.check(&only_events).unwrap_err().to_string();
        assert!(err.contains("contrast") && err.contains("-1"), "{err}");
    }
}
