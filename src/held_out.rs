//! `neuspike evaluate`: methods scored on a held-out `neuspike dataset` set, as
//! `training/evaluate.py` scores them, with tract running the networks as the infer node does
//! (and in 8 bits or bf16: `<name>-int8`, `<name>-bf16`), so a precision's cost in accuracy is
//! measured on the same samples without PyTorch or onnxruntime.
//!
//! Per sample: the method's luminance (a network's rate times the sample's `lum_per_rate`,
//! clipped to [0, 1] by the infer node's own conversion; TFP and TFI as the set holds them),
//! its PSNR and SSIM against the truth (docs/definitions.md); then the mean over every sample,
//! the normal and the complex ones (`complex` in `samples.csv`) and each light scale.

use std::path::{Path, PathBuf};

use eyre::{WrapErr, bail, eyre};
use ndarray::{Array2, ArrayView2, ArrayView3};
use neuspike_dataset::table::Table;
use neuspike_formats::npy::NpyFrames;
use neuspike_reconstruction::learned::{LearnedModel, LearnedOutput, network_variant};

/// `neuspike evaluate`'s options.
#[derive(clap::Args, Clone, Debug)]
pub struct EvaluateOptions {
    /// The held-out set: a `neuspike dataset --split test` folder.
    #[arg(long)]
    pub test: PathBuf,
    /// Methods, comma-separated: `tfp` and `tfi` (the set's own), and networks by file stem in
    /// `--models` (`neuspike-spike-8`), in 8 bits with `-int8` (`neuspike-spike-8-int8`), in bf16
    /// with `-bf16`.
    #[arg(long, value_delimiter = ',', default_value = "tfp,tfi")]
    pub methods: Vec<String>,
    /// The folder of the networks.
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Threads tract runs the networks on.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
}

/// One sample's row of `samples.csv`: what the groups need.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleRow {
    /// The shard folder it lies in (`000`, `001`, ..).
    pub shard: usize,
    /// Its light scale.
    pub light: f64,
    /// Luminance per firing rate (spikes per tick).
    pub lum_per_rate: f64,
    /// Dark or fast: light <= 0.1 or speed >= 3,000 px/s.
    pub complex: bool,
}

/// A group's mean scores.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupScore {
    /// Mean PSNR, dB.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Samples.
    pub n: usize,
}

/// A method's scores: `all`, `normal`, `complex` and `light <x>` groups.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodScores {
    /// The method's name.
    pub method: String,
    /// By group name, in the order `all`, `normal`, `complex`, then the light scales rising.
    pub groups: Vec<(String, GroupScore)>,
}

impl MethodScores {
    /// The group of that name.
    pub fn group(&self, name: &str) -> Option<GroupScore> {
        self.groups.iter().find(|(g, _)| g == name).map(|(_, s)| *s)
    }
}

/// The rows of `<set>/samples.csv`, in sample order.
///
/// # Errors
/// A missing file, a header without `shard`, `light`, `lum_per_rate` or `complex`, or a row
/// whose field does not parse (named with its line).
pub fn read_samples(set: &Path) -> eyre::Result<Vec<SampleRow>> {
    let table = Table::read(
        &set.join("samples.csv"),
        " (is it a `neuspike dataset` folder?)",
    )?;
    let (shard, light, lum, complex) = (
        table.column("shard")?,
        table.column("light")?,
        table.column("lum_per_rate")?,
        table.column("complex")?,
    );
    table
        .rows()
        .map(|row| {
            Ok(SampleRow {
                shard: row.parse(shard, "shard", "a shard number")?,
                light: row.number(light, "light")?,
                lum_per_rate: row.number(lum, "lum_per_rate")?,
                complex: match row.field(complex, "complex")? {
                    "1" => true,
                    "0" => false,
                    v => return Err(row.bad("complex", v, "0 or 1")),
                },
            })
        })
        .collect()
}

/// How a method makes a sample's luminance.
enum Engine {
    /// Read from the set's `<name>.npy` (`tfp`, `tfi`).
    Stored(&'static str),
    /// A network; its inputs' files in its order.
    Net(Box<LearnedModel>),
}

impl Engine {
    fn of(method: &str, models: &Path) -> eyre::Result<Engine> {
        match method {
            "tfp" => return Ok(Engine::Stored("tfp")),
            "tfi" => return Ok(Engine::Stored("tfi")),
            _ => {}
        }
        let (stem, precision) = network_variant(method);
        let path = models.join(format!("{stem}.onnx"));
        if !path.is_file() {
            bail!(
                "--methods {method}: not tfp, tfi or a network in {} ({} is not there)",
                models.display(),
                path.display()
            );
        }
        let mut net = LearnedModel::load(&path).map_err(|e| eyre!("{}: {e}", path.display()))?;
        net.set_precision(precision);
        Ok(Engine::Net(Box::new(net)))
    }

    /// The set's files this method reads, one sample at a time.
    fn files(&self) -> Vec<&'static str> {
        match self {
            Engine::Stored(name) => vec![name],
            Engine::Net(net) => net.inputs().iter().map(|i| i.onnx_name()).collect(),
        }
    }

    /// The luminance of one sample from its files' values (`[C, S, S]` each, or `[S, S]`).
    fn luminance(
        &mut self,
        values: &[Vec<f32>],
        side: (usize, usize),
        lum_per_rate: f64,
    ) -> eyre::Result<Array2<f32>> {
        match self {
            Engine::Stored(_) => {
                Ok(Array2::from_shape_vec(side, values[0].clone()).wrap_err("a stored frame")?)
            }
            Engine::Net(net) => {
                let views = values
                    .iter()
                    .map(|v| {
                        ArrayView3::from_shape((v.len() / (side.0 * side.1), side.0, side.1), v)
                            .wrap_err("a representation")
                    })
                    .collect::<eyre::Result<Vec<_>>>()?;
                let out = net.run(&views).map_err(|e| eyre!("{e}"))?;
                let gain = match net.output() {
                    LearnedOutput::Rate => lum_per_rate,
                    LearnedOutput::Luminance => 1.0,
                };
                let mut lum = Array2::zeros(out.dim());
                neuspike_reconstruction::luminance_from_rate_into(
                    out.view(),
                    gain,
                    1.0,
                    lum.view_mut(),
                )
                .map_err(|e| eyre!("{e}"))?;
                Ok(lum)
            }
        }
    }
}

/// PSNR and SSIM of every sample of `set` for `method`, in sample order.
///
/// # Errors
/// An unknown method, a shard or file that is missing or does not match `samples.csv`, or a
/// network that fails.
pub fn score_samples(
    set: &Path,
    rows: &[SampleRow],
    method: &str,
    models: &Path,
) -> eyre::Result<Vec<(f64, f64)>> {
    let mut engine = Engine::of(method, models)?;
    let mut out = Vec::with_capacity(rows.len());
    let shards = rows.iter().map(|r| r.shard).max().map_or(0, |m| m + 1);
    let mut values = vec![Vec::new(); engine.files().len()];
    let mut truth = Vec::new();
    for shard in 0..shards {
        let dir = set.join(format!("{shard:03}"));
        let open = |name: &str| {
            NpyFrames::open_samples(dir.join(format!("{name}.npy"))).map_err(|e| eyre!("{e}"))
        };
        let mut truths = open("truth")?;
        let mut inputs = engine
            .files()
            .iter()
            .map(|f| open(f))
            .collect::<eyre::Result<Vec<_>>>()?;
        let (n, h, w) = truths.shape();
        let in_shard: Vec<&SampleRow> = rows.iter().filter(|r| r.shard == shard).collect();
        if in_shard.len() != n {
            bail!(
                "{}: {n} samples, samples.csv says {} in shard {shard}",
                dir.join("truth.npy").display(),
                in_shard.len()
            );
        }
        for (f, input) in engine.files().iter().zip(&inputs) {
            let (m, ih, iw) = input.shape();
            if (m, ih, iw) != (n, h, w) {
                bail!(
                    "{}: {m} samples of {ih}x{iw}, truth.npy {n} of {h}x{w}",
                    dir.join(format!("{f}.npy")).display()
                );
            }
        }
        for row in in_shard {
            truths.read_frame(&mut truth).map_err(|e| eyre!("{e}"))?;
            for (input, v) in inputs.iter_mut().zip(&mut values) {
                input.read_frame(v).map_err(|e| eyre!("{e}"))?;
            }
            let lum = engine.luminance(&values, (h, w), row.lum_per_rate)?;
            let gt = ArrayView2::from_shape((h, w), &truth).wrap_err("a truth frame")?;
            out.push((
                neuspike_metrics::psnr(lum.view(), gt),
                neuspike_metrics::ssim(lum.view(), gt),
            ));
        }
    }
    Ok(out)
}

/// The group means of per-sample scores (`all`, `normal`, `complex`, each light scale).
pub fn groups(rows: &[SampleRow], scores: &[(f64, f64)]) -> Vec<(String, GroupScore)> {
    let mean = |keep: &dyn Fn(&SampleRow) -> bool| {
        let picked: Vec<(f64, f64)> = rows
            .iter()
            .zip(scores)
            .filter(|(r, _)| keep(r))
            .map(|(_, s)| *s)
            .collect();
        let n = picked.len();
        // No sample: NaN, not 0 (a mean of nothing is no score).
        let avg = |f: fn(&(f64, f64)) -> f64| picked.iter().map(f).sum::<f64>() / n as f64;
        GroupScore {
            psnr: avg(|s| s.0),
            ssim: avg(|s| s.1),
            n,
        }
    };
    let mut out = vec![
        ("all".to_string(), mean(&|_| true)),
        ("normal".to_string(), mean(&|r| !r.complex)),
        ("complex".to_string(), mean(&|r| r.complex)),
    ];
    let mut lights: Vec<f64> = rows.iter().map(|r| r.light).collect();
    lights.sort_by(f64::total_cmp);
    lights.dedup();
    for light in lights {
        out.push((format!("light {light}"), mean(&|r| r.light == light)));
    }
    out
}

/// Every method's scores on `opts.test`.
///
/// # Errors
/// As [`read_samples`] and [`score_samples`].
pub fn run(opts: &EvaluateOptions) -> eyre::Result<Vec<MethodScores>> {
    neuspike_reconstruction::learned::set_threads(opts.threads);
    let rows = read_samples(&opts.test)?;
    if rows.is_empty() {
        bail!("{}: no samples", opts.test.join("samples.csv").display());
    }
    opts.methods
        .iter()
        .map(|m| {
            let scores = score_samples(&opts.test, &rows, m, &opts.models)?;
            Ok(MethodScores {
                method: m.clone(),
                groups: groups(&rows, &scores),
            })
        })
        .collect()
}

/// The Markdown tables `training/evaluate.py` prints: normal and complex, then per light scale.
pub fn tables(scores: &[MethodScores]) -> String {
    let mut s = String::from(
        "| method | PSNR normal | PSNR complex | SSIM normal | SSIM complex |\n|---|---|---|---|---|\n",
    );
    for m in scores {
        let (n, c) = (m.group("normal"), m.group("complex"));
        let f = |g: Option<GroupScore>, psnr: bool| {
            g.map_or("-".into(), |g| {
                if psnr {
                    format!("{:.2}", g.psnr)
                } else {
                    format!("{:.3}", g.ssim)
                }
            })
        };
        s += &format!(
            "| {} | {} | {} | {} | {} |\n",
            m.method,
            f(n, true),
            f(c, true),
            f(n, false),
            f(c, false)
        );
    }
    let lights: Vec<&String> = scores
        .first()
        .map(|m| {
            m.groups
                .iter()
                .map(|(g, _)| g)
                .filter(|g| g.starts_with("light "))
                .collect()
        })
        .unwrap_or_default();
    if !lights.is_empty() {
        s += "\nPSNR per light scale:\n\n| method |";
        for l in &lights {
            s += &format!(" {l} |");
        }
        s += &format!("\n|---|{}\n", "---|".repeat(lights.len()));
        for m in scores {
            s += &format!("| {} |", m.method);
            for l in &lights {
                s += &m
                    .group(l)
                    .map_or(" - |".into(), |g| format!(" {:.2} |", g.psnr));
            }
            s.push('\n');
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_dataset::{DatasetOptions, Split, generate, tiny_options};

    fn set(dir: &Path) -> PathBuf {
        let out = dir.join("set");
        let o = DatasetOptions {
            size: 32,
            ..tiny_options(Split::Test, out.clone())
        };
        generate(&o, false).expect("a set");
        out
    }

    #[test]
    fn scores_the_sets_frames_and_a_network_in_both_precisions() {
        let dir = tempfile::tempdir().expect("tempdir");
        let test = set(dir.path());
        let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models");
        let rows = read_samples(&test).expect("rows");
        assert_eq!(rows.len(), 25);
        // TFP's scores are the metrics of the set's own frames, sample by sample.
        let tfp = score_samples(&test, &rows, "tfp", &models).expect("tfp");
        let frames: ndarray::Array3<f32> =
            ndarray_npy::read_npy(test.join("001/tfp.npy")).expect("tfp.npy");
        let truth: ndarray::Array3<f32> =
            ndarray_npy::read_npy(test.join("001/truth.npy")).expect("truth.npy");
        for k in 0..frames.dim().0 {
            let (f, t) = (
                frames.index_axis(ndarray::Axis(0), k),
                truth.index_axis(ndarray::Axis(0), k),
            );
            assert_eq!(
                tfp[10 + k],
                (neuspike_metrics::psnr(f, t), neuspike_metrics::ssim(f, t))
            );
        }
        let g = groups(&rows, &tfp);
        let all = g.iter().find(|(n, _)| n == "all").expect("all").1;
        assert_eq!(all.n, 25);
        let expected = tfp.iter().map(|s| s.0).sum::<f64>() / 25.0;
        assert!((all.psnr - expected).abs() < 1e-12);
        // 5 light scales of 5 samples; normal and complex split them.
        assert_eq!(g.len(), 3 + 5);
        assert!(g[3..].iter().all(|(_, s)| s.n == 5));
        let (n, c) = (g[1].1.n, g[2].1.n);
        assert_eq!(n + c, 25);
        assert!(n > 0 && c > 0);
        // A network's score of a sample is that of its own run on the sample's representation.
        let per_sample = score_samples(&test, &rows, "neuspike-spike-8", &models).expect("net");
        let spike: ndarray::Array4<f32> =
            ndarray_npy::read_npy(test.join("000/spike.npy")).expect("spike.npy");
        let truth0: ndarray::Array3<f32> =
            ndarray_npy::read_npy(test.join("000/truth.npy")).expect("truth.npy");
        let mut net = LearnedModel::load(&models.join("neuspike-spike-8.onnx")).expect("model");
        let rate = net
            .run(&[spike.index_axis(ndarray::Axis(0), 3)])
            .expect("runs");
        let mut lum = Array2::zeros(rate.dim());
        neuspike_reconstruction::luminance_from_rate_into(
            rate.view(),
            rows[3].lum_per_rate,
            1.0,
            lum.view_mut(),
        )
        .expect("luminance");
        let gt = truth0.index_axis(ndarray::Axis(0), 3);
        assert_eq!(
            per_sample[3],
            (
                neuspike_metrics::psnr(lum.view(), gt),
                neuspike_metrics::ssim(lum.view(), gt)
            )
        );
        // It beats TFP on the set (32x32 scenes: by little); 8 bits stays within 0.5 dB of f32.
        let net = groups(&rows, &per_sample);
        let int8 = groups(
            &rows,
            &score_samples(&test, &rows, "neuspike-spike-8-int8", &models).expect("int8"),
        );
        assert!(
            net[0].1.psnr > all.psnr,
            "{} vs tfp {}",
            net[0].1.psnr,
            all.psnr
        );
        assert!(
            (net[0].1.psnr - int8[0].1.psnr).abs() < 0.5,
            "{net:?} {int8:?}"
        );
        let table = tables(&[MethodScores {
            method: "tfp".into(),
            groups: g,
        }]);
        assert!(
            table.contains("| tfp |") && table.contains("light 0.05"),
            "{table}"
        );
    }

    #[test]
    fn bad_sets_and_methods_are_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models");
        let err = read_samples(dir.path()).expect_err("no set").to_string();
        assert!(
            err.contains("samples.csv") && err.contains("dataset"),
            "{err}"
        );
        let test = set(dir.path());
        let rows = read_samples(&test).expect("rows");
        let err = score_samples(&test, &rows, "neuspike-none-4", &models)
            .expect_err("no such network")
            .to_string();
        assert!(
            err.contains("neuspike-none-4") && err.contains("not there"),
            "{err}"
        );
        // A field that does not parse is named with its line.
        let csv = std::fs::read_to_string(test.join("samples.csv")).expect("csv");
        let mut lines: Vec<String> = csv.lines().map(String::from).collect();
        let light = lines[0]
            .split(',')
            .position(|h| h == "light")
            .expect("light");
        let mut f: Vec<String> = lines[3].split(',').map(String::from).collect();
        f[light] = "dim".into();
        lines[3] = f.join(",");
        std::fs::write(test.join("samples.csv"), lines.join("\n")).expect("write");
        let err = read_samples(&test).expect_err("bad light").to_string();
        assert!(
            err.contains("line 4") && err.contains("`light`") && err.contains("\"dim\""),
            "{err}"
        );
        // A shard with fewer samples than the rows say.
        std::fs::write(
            test.join("samples.csv"),
            csv + "99,1,x,1,0,0,0.2,0.2,1,0,0\n",
        )
        .expect("write");
        let rows = read_samples(&test).expect("rows");
        let err = score_samples(&test, &rows, "tfp", &models)
            .expect_err("short")
            .to_string();
        assert!(
            err.contains("truth.npy") && err.contains("samples.csv says"),
            "{err}"
        );
    }
}
