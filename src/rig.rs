//! `neuspike calibrate-rig`: the homography and clock offset of a rig of two cameras, estimated
//! from a stretch of what both recorded ([`neuspike_align::rig`]), printed as the arguments the
//! event source and align take.

use std::path::PathBuf;

use eyre::{WrapErr, bail, eyre};
use neuspike_align::rig::{self, Clock, RigEstimate};
use neuspike_formats::ReadOptions;
use neuspike_geometry::Homography;
use neuspike_schemas::EventBatch;

/// The most events read (the estimate uses at most [`rig::MAX_EVENTS`] of them).
const MAX_EVENTS_READ: usize = 20_000_000;

/// `neuspike calibrate-rig`'s options.
#[derive(Clone, Debug, clap::Args)]
pub struct RigOptions {
    /// The spike camera's recording (PKU `.dat`).
    #[arg(long)]
    pub spikes: PathBuf,
    /// The event camera's recording, any event format `neuspike info` reads, on its own clock.
    #[arg(long)]
    pub events: PathBuf,
    /// The spike camera's size, `WxH`.
    #[arg(long, default_value = "400x250", value_parser = parse_size)]
    pub spike_size: (usize, usize),
    /// The event camera's size when its file does not state it, `WxH`.
    #[arg(long, value_parser = parse_size)]
    pub event_size: Option<(usize, usize)>,
    /// Spike planes to use, from `--skip-planes` on.
    #[arg(long, default_value_t = 800)]
    pub planes: usize,
    /// Spike planes to pass over first: the stretch used should hold a change of the motion (a
    /// start, a stop, a turn of direction), which alone tells the clock offset from the
    /// homography.
    #[arg(long, default_value_t = 0)]
    pub skip_planes: u64,
    /// Where to start: a homography (nine numbers). By default, square pixels, the two frames'
    /// widths and centres together.
    #[arg(long, value_parser = parse_homography, allow_hyphen_values = true)]
    pub init: Option<Homography>,
    /// The clock offset when it is known (the event camera's clock minus the spike camera's):
    /// then only the homography is estimated.
    #[arg(long, allow_negative_numbers = true)]
    pub clock_offset_ns: Option<i64>,
    /// The largest clock offset searched, either way.
    #[arg(long, default_value_t = 10_000_000)]
    pub max_offset_ns: i64,
}

fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let (w, h) = text
        .split_once('x')
        .ok_or_else(|| format!("`{text}`: a size is WxH, e.g. 346x260"))?;
    let n = |v: &str| {
        v.parse::<usize>()
            .ok()
            .filter(|&v| (1..=65_535).contains(&v))
            .ok_or_else(|| format!("`{text}`: `{v}` is not a size in 1..=65535"))
    };
    Ok((n(w)?, n(h)?))
}

fn parse_homography(text: &str) -> Result<Homography, String> {
    Homography::parse(text).map_err(|e| e.to_string())
}

/// Reads both recordings and estimates the rig.
///
/// # Errors
/// A file cannot be read, is too short, or the estimate has too little to go on.
pub fn run(opts: &RigOptions) -> eyre::Result<(RigEstimate, (u16, u16))> {
    let (sw, sh) = opts.spike_size;
    let mut pku = neuspike_formats::pku::PkuOptions::default();
    pku.geometry.width = sw;
    pku.geometry.height = sh;
    let available = neuspike_formats::pku::plane_count(&opts.spikes, &pku.geometry)
        .wrap_err_with(|| format!("--spikes {}", opts.spikes.display()))?;
    if opts.skip_planes >= available {
        bail!(
            "--skip-planes {}: --spikes {} holds {available} planes",
            opts.skip_planes,
            opts.spikes.display()
        );
    }
    let planes = usize::try_from(available - opts.skip_planes)
        .unwrap_or(usize::MAX)
        .min(opts.planes);
    if planes == 0 {
        bail!("--spikes {}: no planes", opts.spikes.display());
    }
    let spikes = neuspike_formats::pku::PkuReader::open(&opts.spikes, &pku)
        .and_then(|mut r| {
            // Passed over in pieces, so a long skip holds no more than a piece.
            let mut left = opts.skip_planes;
            while left > 0 {
                let n = usize::try_from(left.min(4096)).unwrap_or(4096);
                if r.next_chunk(n)?.is_none() {
                    break;
                }
                left -= n as u64;
            }
            r.next_chunk(planes)
        })
        .wrap_err_with(|| format!("--spikes {}", opts.spikes.display()))?
        .ok_or_else(|| eyre!("--spikes {}: no planes", opts.spikes.display()))?;
    let read = ReadOptions {
        resolution: opts
            .event_size
            .map(|(w, h)| neuspike_formats::Resolution::new(w as u16, h as u16)),
        ..ReadOptions::default()
    };
    let mut reader = neuspike_formats::open_events(&opts.events, &read)
        .wrap_err_with(|| format!("--events {}", opts.events.display()))?;
    let r = reader.resolution();
    let mut events = EventBatch::empty(usize::from(r.width), usize::from(r.height), 0, 0, 0);
    // The events over the spike stretch, and the largest offset either side.
    let t_first = events_window_start(spikes.t_first_ns, opts.max_offset_ns);
    let t_last = spikes
        .plane_time_ns(planes)
        .saturating_add(opts.max_offset_ns.max(0));
    let mut scratch = EventBatch::empty(usize::from(r.width), usize::from(r.height), 0, 0, 0);
    while events.len() < MAX_EVENTS_READ {
        scratch.t_ns.clear();
        scratch.x.clear();
        scratch.y.clear();
        scratch.polarity.clear();
        if reader
            .read_into(&mut scratch, 1 << 16)
            .wrap_err_with(|| format!("--events {}", opts.events.display()))?
            == 0
        {
            break;
        }
        for i in 0..scratch.len() {
            let e = scratch.get(i);
            if e.t_ns >= t_first && e.t_ns < t_last {
                events.push(e);
            }
        }
        if scratch.t_ns.last().is_some_and(|&t| t >= t_last) {
            break;
        }
    }
    let init = match opts.init {
        Some(h) => h,
        None => {
            let k = sw as f64 / f64::from(r.width.max(1));
            let (ew, eh) = (f64::from(r.width), f64::from(r.height));
            Homography::scale_translate(
                k,
                k,
                sw as f64 / 2.0 - ew / 2.0 * k,
                sh as f64 / 2.0 - eh / 2.0 * k,
            )?
        }
    };
    let clock = match opts.clock_offset_ns {
        Some(ns) => Clock::Known(ns),
        None => Clock::Within(opts.max_offset_ns),
    };
    let est = rig::estimate(&spikes, &events, init, clock).map_err(|e| {
        eyre!(
            "{} and {}: {e}",
            opts.spikes.display(),
            opts.events.display()
        )
    })?;
    Ok((est, (r.width, r.height)))
}

/// The first event time worth reading: the spike stretch's start less the largest offset.
fn events_window_start(t_first_ns: i64, max_offset_ns: i64) -> i64 {
    t_first_ns.saturating_sub(max_offset_ns.max(0))
}

/// The estimate as the arguments the two nodes take.
pub fn arguments(est: &RigEstimate, event_size: (u16, u16)) -> String {
    format!(
        "event source: --width {} --height {} --homography {}\nalign: --homography {} --event-offset-ns {}",
        event_size.0, event_size.1, est.homography, est.homography, -est.offset_ns
    )
}
