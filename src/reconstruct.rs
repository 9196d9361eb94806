//! `neuspike reconstruct`: frames from a recorded spike file, through a graph written for the
//! run. The graph is saved in the output folder beside the frames (`graph.yml`, with a `types`
//! link to the message types), so the run can be repeated with the stock dora CLI too.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use eyre::WrapErr;

use crate::graph;

/// Classical reconstructions a recording can go through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Texture from playback: mean firing over the window.
    Tfp,
    /// Texture from inter-spike intervals at the reference plane.
    Tfi,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Tfp => "tfp",
            Method::Tfi => "tfi",
        }
    }

    /// The representation the method reconstructs from (the represent node's output).
    fn representation(self) -> &'static str {
        match self {
            Method::Tfp => "tfp",
            Method::Tfi => "isi",
        }
    }
}

/// What to reconstruct.
#[derive(Clone, Debug)]
pub struct ReconstructOptions {
    /// The PKU spike `.dat`.
    pub spikes: PathBuf,
    /// An event file to align with the spikes (refused: the file-driven graph takes spikes only).
    pub events: Option<PathBuf>,
    /// The method.
    pub method: Method,
    /// Output folder.
    pub out: PathBuf,
    /// Extra spike-source arguments (resolution, head columns, rate, start, calibration).
    pub source_args: String,
    /// Planes per window and planes between frames.
    pub window_planes: u32,
    /// Planes between two frames.
    pub stride_planes: u32,
    /// PNG bit depth.
    pub bit_depth: u8,
    /// Run the graph's `build:` command first.
    pub build: bool,
}

/// The repository the program was built from (node binaries and message types live there).
fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The graph for `opts`, with absolute paths (it lives in the output folder).
pub fn graph_yaml(opts: &ReconstructOptions, spikes: &Path, out: &Path) -> String {
    let repo = repo();
    let bin = |name: &str| repo.join("target/release").join(format!("neuspike-{name}"));
    let build = format!(
        "cargo build --release --manifest-path {} --workspace --bins",
        repo.join("Cargo.toml").display()
    );
    let queue = "queue_size: 1000, queue_policy: backpressure";
    let (m, r) = (opts.method.name(), opts.method.representation());
    let mut y = String::new();
    let _ = write!(
        y,
        "# Written by `neuspike reconstruct`: {m} frames of {spikes}.\n\
         nodes:\n\
         \x20 - id: spike-source\n\
         \x20   build: {build}\n\
         \x20   path: {source}\n\
         \x20   args: --file {spikes} --chunk-planes 20 {extra}\n\
         \x20   env: {{ DORA_RUNTIME_TYPE_CHECK: error }}\n\
         \x20   outputs: [spikes]\n\
         \x20   output_types: {{ spikes: neuspike/messages/v1/SpikeChunk }}\n\
         \x20 - id: align\n\
         \x20   build: {build}\n\
         \x20   path: {align}\n\
         \x20   args: --window-planes {wp} --stride-planes {sp}\n\
         \x20   env: {{ DORA_RUNTIME_TYPE_CHECK: error }}\n\
         \x20   inputs: {{ spikes: {{ source: spike-source/spikes, {queue} }} }}\n\
         \x20   input_types: {{ spikes: neuspike/messages/v1/SpikeChunk }}\n\
         \x20   outputs: [windows]\n\
         \x20   output_types: {{ windows: neuspike/messages/v1/AlignedWindow }}\n\
         \x20 - id: represent\n\
         \x20   build: {build}\n\
         \x20   path: {represent}\n\
         \x20   args: --tfp-planes {wp}\n\
         \x20   env: {{ DORA_RUNTIME_TYPE_CHECK: error }}\n\
         \x20   inputs: {{ windows: {{ source: align/windows, {queue} }} }}\n\
         \x20   input_types: {{ windows: neuspike/messages/v1/AlignedWindow }}\n\
         \x20   outputs: [{r}]\n\
         \x20   output_types: {{ {r}: neuspike/messages/v1/Representation }}\n\
         \x20 - id: infer-{m}\n\
         \x20   build: {build}\n\
         \x20   path: {infer}\n\
         \x20   args: --method {m}\n\
         \x20   env: {{ DORA_RUNTIME_TYPE_CHECK: error }}\n\
         \x20   inputs: {{ representation: {{ source: represent/{r}, {queue} }} }}\n\
         \x20   input_types: {{ representation: neuspike/messages/v1/Representation }}\n\
         \x20   outputs: [frames]\n\
         \x20   output_types: {{ frames: neuspike/messages/v1/Frame }}\n\
         \x20 - id: sink\n\
         \x20   build: {build}\n\
         \x20   path: {sink}\n\
         \x20   args: --out {out} --bit-depth {depth}\n\
         \x20   inputs: {{ {m}: {{ source: infer-{m}/frames, {queue} }} }}\n\
         \x20   input_types: {{ {m}: neuspike/messages/v1/Frame }}\n",
        spikes = spikes.display(),
        source = bin("spike-source").display(),
        extra = opts.source_args,
        align = bin("align").display(),
        wp = opts.window_planes,
        sp = opts.stride_planes,
        represent = bin("represent").display(),
        infer = bin("infer").display(),
        sink = bin("sink").display(),
        out = out.display(),
        depth = opts.bit_depth,
    );
    y
}

/// Writes the graph into the output folder and runs it.
pub fn reconstruct(opts: &ReconstructOptions) -> eyre::Result<graph::Report> {
    if let Some(events) = &opts.events {
        eyre::bail!(
            "--events {}: the file-driven graph does not take an event file yet; the event \
             methods (hf, cf, fusion) run in graphs/fusion.yml on simulated cameras of one size; \
             run without --events",
            events.display()
        );
    }
    let spikes = std::fs::canonicalize(&opts.spikes)
        .wrap_err_with(|| format!("--spikes {}: cannot open", opts.spikes.display()))?;
    std::fs::create_dir_all(&opts.out)
        .wrap_err_with(|| format!("cannot create {}", opts.out.display()))?;
    let out = std::fs::canonicalize(&opts.out)?;
    let types = out.join("types");
    if !types.exists() {
        link_dir(&repo().join("schemas/types"), &types)?;
    }
    let graph_path = out.join("graph.yml");
    std::fs::write(&graph_path, graph_yaml(opts, &spikes, &out))
        .wrap_err_with(|| format!("cannot write {}", graph_path.display()))?;
    graph::run(&graph_path, &[], opts.build, None, Some(out))
}

#[cfg(unix)]
fn link_dir(target: &Path, link: &Path) -> eyre::Result<()> {
    std::os::unix::fs::symlink(target, link)
        .wrap_err_with(|| format!("cannot link {} to {}", link.display(), target.display()))
}

#[cfg(not(unix))]
fn link_dir(target: &Path, link: &Path) -> eyre::Result<()> {
    eyre::bail!(
        "cannot link {} to {}: only supported on unix",
        link.display(),
        target.display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(method: Method) -> ReconstructOptions {
        ReconstructOptions {
            spikes: "x.dat".into(),
            events: None,
            method,
            out: "out".into(),
            source_args: "--file-width 40 --file-height 25".into(),
            window_planes: 33,
            stride_planes: 10,
            bit_depth: 8,
            build: false,
        }
    }

    #[test]
    fn the_graph_wires_the_method_to_its_representation() {
        for (method, repr) in [(Method::Tfp, "tfp"), (Method::Tfi, "isi")] {
            let y = graph_yaml(&opts(method), Path::new("/d/x.dat"), Path::new("/o"));
            let g: serde_yaml::Value = serde_yaml::from_str(&y).expect("valid YAML");
            let nodes = g["nodes"].as_sequence().expect("nodes");
            assert_eq!(nodes.len(), 5);
            let infer = &nodes[3];
            let m = method.name();
            assert_eq!(infer["id"].as_str(), Some(format!("infer-{m}").as_str()));
            assert_eq!(
                infer["inputs"]["representation"]["source"].as_str(),
                Some(format!("represent/{repr}").as_str())
            );
            assert_eq!(nodes[2]["outputs"][0].as_str(), Some(repr));
            let src_args = nodes[0]["args"].as_str().expect("args");
            assert!(src_args.contains("--file /d/x.dat") && src_args.contains("--file-width 40"));
            assert_eq!(
                nodes[4]["inputs"][m]["queue_policy"].as_str(),
                Some("backpressure")
            );
        }
    }

    #[test]
    fn events_are_refused_by_name() {
        let mut o = opts(Method::Tfp);
        o.events = Some("e.raw".into());
        let e = match reconstruct(&o) {
            Ok(_) => panic!("--events was accepted"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("e.raw"), "{e}");
    }
}
