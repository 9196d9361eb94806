//! `neuspike calibrate`: the spike camera's noise model against a real recording.
//!
//! The recording's still pixels, in three bands of firing rate, give inter-spike-interval
//! histograms; the model, lit pixel by pixel to the same rates, gives its own
//! ([`neuspike_spike_camera::calibrate`]). The command scores the paper's model, each per-interval
//! term added alone, SCSim's values and the fitted model, writes the table (`calibration.md`),
//! the histograms (`isi.png`) and the fitted profile (`profile.yml`, the file `--profile` reads).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use eyre::{WrapErr, bail, eyre};
use neuspike_spike_camera::calibrate::{self, BANDS, Histogram, Reference, Score};
use neuspike_spike_camera::noise::{Noise, ProfileFile};
use plotters::prelude::*;

/// The recording is read up to this many planes (the reader allocates what it is asked for).
const MAX_PLANES: u64 = 20_000;

/// `neuspike calibrate`'s options.
#[derive(Clone, Debug, clap::Args)]
pub struct CalibrateOptions {
    /// The real recording (PKU `.dat`, 400x250 unless --width/--height say otherwise).
    #[arg(long)]
    pub real: PathBuf,
    /// Sensor width of the recording.
    #[arg(long, default_value_t = 400)]
    pub width: usize,
    /// Sensor height of the recording.
    #[arg(long, default_value_t = 250)]
    pub height: usize,
    /// Where calibration.md, isi.png and profile.yml go.
    #[arg(long, default_value = "out/calibrate")]
    pub out: PathBuf,
    /// The profile's name.
    #[arg(long, default_value = "vidar")]
    pub name: String,
    /// Seed of the simulated pixels.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// One model of the table.
pub struct Scored {
    /// What it is.
    pub label: String,
    /// Its terms.
    pub noise: Noise,
    /// Its distances.
    pub score: Score,
}

/// What `calibrate` found.
pub struct Calibration {
    /// The compared models, the fitted one last.
    pub models: Vec<Scored>,
    /// Still pixels per band.
    pub pixels: Vec<usize>,
    /// Planes read.
    pub planes: usize,
    /// The profile written.
    pub profile: ProfileFile,
}

/// Reads the recording, scores the models, fits, and writes the report, plot and profile.
///
/// # Errors
/// The recording cannot be read or is too short, or an output cannot be written.
pub fn run(opts: &CalibrateOptions) -> eyre::Result<Calibration> {
    let path = &opts.real;
    let mut pku = neuspike_formats::pku::PkuOptions::default();
    pku.geometry.width = opts.width;
    pku.geometry.height = opts.height;
    let planes = neuspike_formats::pku::plane_count(path, &pku.geometry)
        .wrap_err_with(|| format!("--real {}", path.display()))?;
    let planes = usize::try_from(planes.min(MAX_PLANES)).unwrap_or(0);
    if planes == 0 {
        bail!("--real {}: no planes", path.display());
    }
    let mut reader = neuspike_formats::pku::PkuReader::open(path, &pku)
        .wrap_err_with(|| format!("--real {}", path.display()))?;
    let chunk = reader
        .next_chunk(planes)
        .wrap_err_with(|| format!("--real {}", path.display()))?
        .ok_or_else(|| eyre!("--real {}: no planes", path.display()))?;
    let reference =
        Reference::from_recording(&chunk).map_err(|e| eyre!("--real {}: {e}", path.display()))?;
    let pixels: Vec<usize> = (0..BANDS.len())
        .map(|b| reference.pixels.iter().filter(|p| p.2 == b).count())
        .collect();
    if pixels.iter().all(|&n| n == 0) {
        bail!(
            "--real {}: no still pixel in any band of rate",
            path.display()
        );
    }
    let s = Noise::SCSIM;
    let candidates = [
        ("the paper's model", Noise::OFF),
        (
            "+ shot noise (SCSim, 50,000 e-)",
            Noise {
                electrons_per_phi: s.electrons_per_phi,
                ..Noise::OFF
            },
        ),
        (
            "+ threshold jitter (SCSim, 0.58%)",
            Noise {
                threshold_jitter: s.threshold_jitter,
                ..Noise::OFF
            },
        ),
        (
            "+ reset delay (SCSim, 0.002 tick)",
            Noise {
                reset_delay_ticks: s.reset_delay_ticks,
                ..Noise::OFF
            },
        ),
        ("SCSim, every term", s),
    ];
    let mut models: Vec<Scored> = candidates
        .into_iter()
        .map(|(label, noise)| Scored {
            label: label.to_string(),
            noise,
            score: reference.score(&noise, opts.seed),
        })
        .collect();
    let (fitted, score) = calibrate::fit(&reference, &Noise::SCSIM, opts.seed);
    models.push(Scored {
        label: format!("fitted (`{}`)", opts.name),
        noise: fitted,
        score,
    });
    let file = path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let paper = models[0].score.mean_wasserstein;
    let last = &models[models.len() - 1];
    let profile = ProfileFile {
        version: 1,
        name: opts.name.clone(),
        provenance: format!(
            "neuspike calibrate --real {file} ({}x{}, {planes} planes): the per-interval sigma \
             fitted to the ISI histograms of {} still pixels at matched rates (mean Wasserstein-1 \
             {:.3} ticks, the paper's model {paper:.3}); shot noise, gain, threshold offset, dark \
             current and reset delay are SCSim's (v2s.py), which matched rates cannot see; {}",
            opts.width,
            opts.height,
            reference.pixels.len(),
            last.score.mean_wasserstein,
            crate::trade::auto::now_utc(),
        ),
        noise: fitted,
    };
    std::fs::create_dir_all(&opts.out)
        .wrap_err_with(|| format!("cannot create {}", opts.out.display()))?;
    let yaml = serde_yaml::to_string(&profile).wrap_err("profile as YAML")?;
    write(&opts.out.join("profile.yml"), &yaml)?;
    let cal = Calibration {
        models,
        pixels,
        planes,
        profile,
    };
    write(
        &opts.out.join("calibration.md"),
        &report(&cal, &reference.real, &file),
    )?;
    plot(&cal, &reference.real, &opts.out.join("isi.png"))?;
    Ok(cal)
}

fn write(path: &Path, text: &str) -> eyre::Result<()> {
    neuspike_formats::atomic::write(path, text)
        .wrap_err_with(|| format!("cannot write {}", path.display()))
}

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.3}"))
}

/// The markdown report: the table of distances and the histograms' means.
pub fn report(cal: &Calibration, real: &[Histogram], file: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# The spike camera against `{file}`\n");
    let _ = writeln!(
        s,
        "Inter-spike intervals of the recording's still pixels ({} planes), per band of firing \
         rate, against the model lit pixel by pixel to the same rates. W1: Wasserstein-1 distance \
         in ticks; KL: divergence of the real histogram from the model's, nats. Lower is closer.\n",
        cal.planes
    );
    let bands: Vec<String> = BANDS
        .iter()
        .zip(&cal.pixels)
        .zip(real)
        .map(|((b, n), h)| {
            format!(
                "{} (rate {}-{}, {n} px, mean ISI {:.2})",
                b.name,
                b.lo,
                b.hi,
                h.mean()
            )
        })
        .collect();
    let _ = writeln!(s, "Bands: {}.\n", bands.join("; "));
    let mut head = "| model | sigma per interval |".to_string();
    for b in &BANDS {
        let _ = write!(head, " W1 {} | KL {} |", b.name, b.name);
    }
    head.push_str(" mean W1 | mean KL |");
    let _ = writeln!(s, "{head}");
    let _ = writeln!(s, "|{}", "---|".repeat(4 + 2 * BANDS.len()));
    for m in &cal.models {
        let mut row = format!("| {} | {:.4} |", m.label, m.noise.fire_sigma());
        for (w, k) in m.score.wasserstein.iter().zip(&m.score.kl) {
            let _ = write!(row, " {} | {} |", cell(*w), cell(*k));
        }
        let _ = write!(
            row,
            " {:.3} | {:.3} |",
            m.score.mean_wasserstein, m.score.mean_kl
        );
        let _ = writeln!(s, "{row}");
    }
    let _ = writeln!(
        s,
        "\nThe fixed-pattern terms (gain, threshold offset, dark current) only move a pixel's rate, \
         which the comparison matches, so they cannot be fitted here; the profile keeps SCSim's."
    );
    s
}

/// `isi.png`: per band, the real ISI histogram and those of the paper's model and the fitted one.
fn plot(cal: &Calibration, real: &[Histogram], path: &Path) -> eyre::Result<()> {
    let (w, h) = (1200u32, 400u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let text = crate::trade::plot::has_font();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(crate::trade::plot::pe)?;
        let panels = root.split_evenly((1, BANDS.len()));
        let shown = [0, cal.models.len() - 1];
        for (b, panel) in panels.iter().enumerate() {
            // The lengths that hold 99.5% of the real intervals.
            let p = real[b].probabilities();
            let mut cum = 0.0;
            let top = p
                .iter()
                .position(|v| {
                    cum += v;
                    cum > 0.995
                })
                .unwrap_or(p.len() - 1)
                .max(3)
                + 1;
            let ymax = p.iter().copied().fold(0.0, f64::max).max(0.05) * 1.1;
            let mut chart = ChartBuilder::on(panel);
            chart.margin(10);
            if text {
                chart
                    .caption(BANDS[b].name, ("sans-serif", 18))
                    .x_label_area_size(30)
                    .y_label_area_size(40);
            }
            let mut chart = chart
                .build_cartesian_2d(0.5f64..top as f64 + 0.5, 0.0f64..ymax)
                .map_err(crate::trade::plot::pe)?;
            if text {
                chart
                    .configure_mesh()
                    .x_desc("ISI, ticks")
                    .y_desc("share")
                    .draw()
                    .map_err(crate::trade::plot::pe)?;
            }
            let series = |h: &Histogram| -> Vec<(f64, f64)> {
                let p = h.probabilities();
                (1..=top).map(|d| (d as f64, p[d])).collect()
            };
            chart
                .draw_series(series(&real[b]).into_iter().map(|(x, y)| {
                    Rectangle::new(
                        [(x - 0.4, 0.0), (x + 0.4, y)],
                        RGBColor(200, 200, 200).filled(),
                    )
                }))
                .map_err(crate::trade::plot::pe)?
                .label("real")
                .legend(|(x, y)| {
                    Rectangle::new(
                        [(x, y - 4), (x + 12, y + 4)],
                        RGBColor(200, 200, 200).filled(),
                    )
                });
            for (i, &m) in shown.iter().enumerate() {
                let c = crate::trade::plot::colour(i);
                let model = &cal.models[m];
                chart
                    .draw_series(LineSeries::new(
                        series(&model.score.simulated[b]),
                        c.stroke_width(2),
                    ))
                    .map_err(crate::trade::plot::pe)?
                    .label(model.label.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 12, y)], c));
            }
            if text && b == 0 {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .draw()
                    .map_err(crate::trade::plot::pe)?;
            }
        }
        root.present().map_err(crate::trade::plot::pe)?;
    }
    crate::trade::plot::save(buf, (w, h), path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real Vidar recording beside the repository, when there.
    #[test]
    fn the_fit_on_the_real_vidar_beats_the_papers_model_and_writes_a_loadable_profile() {
        let real = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/real/vidar-car-400x250.dat");
        if !real.exists() {
            eprintln!("skipped: {} is absent", real.display());
            return;
        }
        let out = tempfile::tempdir().unwrap();
        let opts = CalibrateOptions {
            real,
            width: 400,
            height: 250,
            out: out.path().to_path_buf(),
            name: "test".into(),
            seed: 1,
        };
        let cal = run(&opts).unwrap();
        let paper = &cal.models[0].score;
        let fitted = &cal.models[cal.models.len() - 1];
        assert!(cal.pixels.iter().all(|&n| n > 1000), "{:?}", cal.pixels);
        assert!(fitted.score.mean_wasserstein < paper.mean_wasserstein);
        assert!(fitted.score.mean_kl < 0.8 * paper.mean_kl);
        assert!(fitted.noise.fire_sigma() > 0.02);
        let profile = out.path().join("profile.yml");
        let loaded = neuspike_spike_camera::noise::profile(profile.to_str().unwrap()).unwrap();
        assert_eq!(loaded, fitted.noise);
        let md = std::fs::read_to_string(out.path().join("calibration.md")).unwrap();
        assert!(md.contains("the paper's model") && md.contains("W1 dark"));
        assert!(out.path().join("isi.png").exists());
    }

    #[test]
    fn a_missing_recording_is_named() {
        let opts = CalibrateOptions {
            real: PathBuf::from("/no/such/file.dat"),
            width: 400,
            height: 250,
            out: std::env::temp_dir().join("neuspike-calibrate-missing"),
            name: "x".into(),
            seed: 1,
        };
        let e = format!("{:#}", run(&opts).err().unwrap());
        assert!(e.contains("/no/such/file.dat"), "{e}");
    }
}
