//! neuspike's Python package (`python/neuspike`) against the Rust schemas, and the example Python
//! node (`examples/python-node`) alone and in a graph.
//!
//! - Messages the Rust side writes (as Arrow IPC, `schemas::ipc`) are read by the Python package,
//!   values checked one for one; damaged ones give the Python package the very error text the
//!   Rust side gives; messages the Python package writes are read back here.
//! - The package's own tests (`python/tests`), with its native module built here by cargo and
//!   laid out as `pip install ./python` lays it out: the library on numpy arrays
//!   (`test_native.py`) and the messages.
//! - The example node's unit test (canned events, no daemon) runs, then its graph, whose frames
//!   must equal the Rust example node's (the same gamma curve) to within one 16-bit level.
//!
//! Each test skips with a printed notice where Python lacks pyarrow and numpy (or dora-rs, for
//! the graph); CI installs them.

mod common;
use common::{python_has, root, run_graph};

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, OnceLock};

use ndarray::{Array2, Array3};
use neuspike_schemas::arrow::array::{ArrayRef, Float32Array, Int32Array, UInt8Array};
use neuspike_schemas::{
    Credit, EventBatch, Frame, FrameKind, Message, Meta, MetaExt, Parameter, Representation,
    RepresentationKind, SpikeChunk, end_of_stream, ipc,
};

/// The Python package as `pip install ./python` lays it out: its modules and the native module,
/// built here by cargo, in `<target>/<profile>/python-package/` (for `PYTHONPATH`).
fn package() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args([
            "build",
            "-p",
            "neuspike-python",
            "--message-format=json-render-diagnostics",
        ]);
        if !cfg!(debug_assertions) {
            cmd.arg("--release");
        }
        let out = cmd.current_dir(root()).output().expect("cargo runs");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "building the native module failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // The cdylib's path, from cargo's artifact message.
        let so = text
            .lines()
            .filter(|l| l.contains("\"name\":\"_native\""))
            .find_map(|l| {
                let end = l.find("lib_native.so\"")? + "lib_native.so".len();
                let start = l[..end].rfind('"')? + 1;
                Some(PathBuf::from(&l[start..end]))
            })
            .expect("cargo names lib_native.so");
        let dir = so.parent().expect("a folder").join("python-package");
        let pkg = dir.join("neuspike");
        let _ = std::fs::remove_dir_all(&pkg);
        std::fs::create_dir_all(&pkg).expect("mkdir");
        for entry in std::fs::read_dir(root().join("python/neuspike")).expect("python/neuspike") {
            let p = entry.expect("entry").path();
            if p.extension()
                .is_some_and(|e| e == "py" || e == "pyi" || e == "typed")
            {
                std::fs::copy(&p, pkg.join(p.file_name().expect("name"))).expect("copy");
            }
        }
        std::fs::copy(&so, pkg.join("_native.abi3.so")).expect("copy the native module");
        dir
    })
}

/// Runs `python3 args` in the root with the package (native module included) first on its path.
fn python(args: &[&str], env: &[(&str, &Path)]) {
    let mut cmd = Command::new("python3");
    cmd.args(args)
        .current_dir(root())
        .env("PYTHONPATH", package())
        .env("NEUSPIKE_REQUIRE_NATIVE", "1");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("python3 runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    assert!(out.status.success(), "python3 {args:?} failed:\n{text}");
}

fn write(dir: &Path, name: &str, urn: &str, meta: &Meta, data: &ArrayRef) {
    let bytes = ipc::encode(urn, meta, data).expect("encode");
    std::fs::write(dir.join(format!("{name}.arrow")), bytes).expect("write");
}

/// The messages both sides agree on (python/tests/test_messages.py builds the same values).
fn frame() -> Frame {
    Frame {
        kind: FrameKind::Reconstruction,
        method: "tfp".into(),
        t_ref_ns: -5,
        compute_ns: 7,
        chosen: None,
        budget_ns: None,
        seq: 3,
        data: Array2::from_shape_fn((2, 3), |(y, x)| (y * 3 + x) as f32 / 8.0),
    }
}

fn representation() -> Representation {
    Representation {
        kind: RepresentationKind::Isi,
        t_ref_ns: 42,
        seq: 1,
        params: [("window".to_string(), 33.0), ("tau_ns".to_string(), 0.25)]
            .into_iter()
            .collect(),
        data: Array3::from_shape_fn((2, 3, 4), |(c, y, x)| (c * 100 + y * 10 + x) as f32),
    }
}

fn spike_chunk() -> SpikeChunk {
    SpikeChunk {
        width: 9,
        height: 2,
        first_plane: 40,
        n_planes: 2,
        t_first_ns: 2_000_000,
        plane_period_ns: 50_000,
        seq: 2,
        bits: vec![0xA5, 0x01, 0x80, 0x00, 0xFF, 0x02],
        lum_per_rate: Some(20.0),
    }
}

fn event_batch() -> EventBatch {
    EventBatch {
        width: 346,
        height: 260,
        t_start_ns: 1_000,
        t_end_ns: 2_000,
        seq: 4,
        t_ns: vec![1_000, 1_500, 1_500, 1_999],
        x: vec![0, 345, 7, 100],
        y: vec![0, 259, 8, 200],
        polarity: vec![1, -1, -1, 1],
    }
}

fn credit() -> Credit {
    Credit {
        hello: true,
        grants: vec![("align/windows".into(), 8), ("represent/tfp".into(), 3)],
    }
}

/// Damaged messages, each with the error the Rust side gives for it.
fn damaged() -> Vec<(&'static str, &'static str, Meta, ArrayRef, String)> {
    let mut out = Vec::new();
    let mut add = |name, urn: &'static str, meta: Meta, data: ArrayRef, err: String| {
        out.push((name, urn, meta, data, err));
    };
    let frame_err =
        |m: &Meta, d: &ArrayRef| Frame::from_arrow(m, d).expect_err("damaged").to_string();
    let rep_err = |m: &Meta, d: &ArrayRef| {
        Representation::from_arrow(m, d)
            .expect_err("damaged")
            .to_string()
    };
    let chunk_err = |m: &Meta, d: &ArrayRef| {
        SpikeChunk::from_arrow(m, d)
            .expect_err("damaged")
            .to_string()
    };
    let batch_err = |m: &Meta, d: &ArrayRef| {
        EventBatch::from_arrow(m, d)
            .expect_err("damaged")
            .to_string()
    };

    let (fm, fd) = frame().to_arrow();
    let tweak = |f: &dyn Fn(&mut Meta)| {
        let mut m = fm.clone();
        f(&mut m);
        m
    };
    let m = tweak(&|m| {
        m.remove("width");
    });
    add(
        "frame-no-width",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let m = tweak(&|m| m.set_string("width", "four \"hundred\""));
    add(
        "frame-width-text",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let m = tweak(&|m| {
        m.insert("seq".into(), Parameter::Bool(true));
    });
    add(
        "frame-seq-bool",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let m = tweak(&|m| {
        m.insert("t_ref_ns".into(), Parameter::Float(0.5));
    });
    add(
        "frame-t-float",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let m = tweak(&|m| m.set_string("kind", "truth"));
    add(
        "frame-kind",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let m = tweak(&|m| m.set_int("height", -3));
    add(
        "frame-height-negative",
        Frame::TYPE_URN,
        m.clone(),
        fd.clone(),
        frame_err(&m, &fd),
    );
    let nan: ArrayRef = Arc::new(Float32Array::from(vec![0.0, 0.1, 0.2, 0.3, 0.4, f32::NAN]));
    add(
        "frame-nan",
        Frame::TYPE_URN,
        fm.clone(),
        nan.clone(),
        frame_err(&fm, &nan),
    );
    let short: ArrayRef = Arc::new(Float32Array::from(vec![0.0; 5]));
    add(
        "frame-short",
        Frame::TYPE_URN,
        fm.clone(),
        short.clone(),
        frame_err(&fm, &short),
    );
    let ints: ArrayRef = Arc::new(Int32Array::from(vec![0; 6]));
    add(
        "frame-int32",
        Frame::TYPE_URN,
        fm.clone(),
        ints.clone(),
        frame_err(&fm, &ints),
    );

    let (rm, rd) = representation().to_arrow();
    let mut m = rm.clone();
    m.set_string("kind", "spike-repr");
    add(
        "rep-kind",
        Representation::TYPE_URN,
        m.clone(),
        rd.clone(),
        rep_err(&m, &rd),
    );
    let mut m = rm.clone();
    m.set_int("seq", -1);
    add(
        "rep-seq-negative",
        Representation::TYPE_URN,
        m.clone(),
        rd.clone(),
        rep_err(&m, &rd),
    );
    let mut m = rm.clone();
    m.set_int("height", 1 << 33);
    add(
        "rep-height-huge",
        Representation::TYPE_URN,
        m.clone(),
        rd.clone(),
        rep_err(&m, &rd),
    );
    let mut values = vec![0.5f32; 24];
    values[17] = f32::NEG_INFINITY;
    let inf: ArrayRef = Arc::new(Float32Array::from(values));
    add(
        "rep-inf",
        Representation::TYPE_URN,
        rm.clone(),
        inf.clone(),
        rep_err(&rm, &inf),
    );

    let (cm, cd) = spike_chunk().to_arrow();
    let mut m = cm.clone();
    m.set_int("plane_period_ns", 0);
    add(
        "chunk-period",
        SpikeChunk::TYPE_URN,
        m.clone(),
        cd.clone(),
        chunk_err(&m, &cd),
    );
    let mut m = cm.clone();
    m.insert("lum_per_rate".into(), Parameter::Float(-1.5));
    add(
        "chunk-lum",
        SpikeChunk::TYPE_URN,
        m.clone(),
        cd.clone(),
        chunk_err(&m, &cd),
    );
    let long: ArrayRef = Arc::new(UInt8Array::from(vec![0u8; 7]));
    add(
        "chunk-long",
        SpikeChunk::TYPE_URN,
        cm.clone(),
        long.clone(),
        chunk_err(&cm, &long),
    );

    for (name, f) in [
        (
            "batch-outside",
            &(|b: &mut EventBatch| b.x[2] = 346) as &dyn Fn(&mut EventBatch),
        ),
        ("batch-polarity", &|b: &mut EventBatch| b.polarity[1] = 0),
        ("batch-order", &|b: &mut EventBatch| b.t_ns[2] = 1_200),
        ("batch-interval", &|b: &mut EventBatch| b.t_ns[3] = 2_000),
    ] {
        let mut b = event_batch();
        f(&mut b);
        let (m, d) = b.to_arrow();
        add(
            name,
            EventBatch::TYPE_URN,
            m.clone(),
            d.clone(),
            batch_err(&m, &d),
        );
    }
    out
}

/// The package's own tests, the native module's included (`python/tests/test_native.py`: every
/// kernel against numpy, files, the simulator, errors, workers); and the messages: Rust writes,
/// Python reads (values and errors); Python writes, Rust reads.
#[test]
fn the_python_package_passes_its_tests_and_reads_and_writes_what_the_rust_schemas_do() {
    if !python_has("pyarrow, numpy") {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let rust = dir.path().join("rust");
    let py = dir.path().join("python");
    std::fs::create_dir_all(&rust).expect("mkdir");
    std::fs::create_dir_all(&py).expect("mkdir");
    let (m, d) = frame().to_arrow();
    write(&rust, "frame", Frame::TYPE_URN, &m, &d);
    let (m, d) = representation().to_arrow();
    write(&rust, "representation", Representation::TYPE_URN, &m, &d);
    let (m, d) = spike_chunk().to_arrow();
    write(&rust, "spike_chunk", SpikeChunk::TYPE_URN, &m, &d);
    let (m, d) = event_batch().to_arrow();
    write(&rust, "event_batch", EventBatch::TYPE_URN, &m, &d);
    let (m, d) = credit().to_arrow();
    write(&rust, "credit", Credit::TYPE_URN, &m, &d);
    let (m, d) = end_of_stream::<Frame>(17);
    write(&rust, "end_of_stream", Frame::TYPE_URN, &m, &d);
    let bad = damaged();
    for (name, urn, meta, data, err) in &bad {
        write(&rust, &format!("bad-{name}"), urn, meta, data);
        std::fs::write(rust.join(format!("bad-{name}.txt")), err).expect("write");
    }

    // A small set as `neuspike dataset` writes it: the package's `Samples` must make the same.
    let set = dir.path().join("set");
    let opts = neuspike_dataset::tiny_options(neuspike_dataset::Split::Train, set.clone());
    neuspike_dataset::generate(&opts, false).expect("a small set");

    // A recording as `neuspike simulate` writes it: the package reads it back.
    let recording = dir.path().join("recording");
    let status = Command::new(env!("CARGO_BIN_EXE_neuspike"))
        .args([
            "simulate",
            "bright-slow",
            "--planes",
            "100",
            "--gt-every-planes",
            "20",
        ])
        .args([
            "--spike=--seed 1",
            "--dvs=--width 400 --height 250 --seed 1",
            "--out",
        ])
        .arg(&recording)
        .status()
        .expect("neuspike simulate runs");
    assert!(status.success(), "neuspike simulate failed");

    python(
        &["-m", "unittest", "discover", "-v", "-s", "python/tests"],
        &[
            ("NEUSPIKE_RUST_MESSAGES", &rust),
            ("NEUSPIKE_PYTHON_OUT", &py),
            ("NEUSPIKE_DATASET_DIR", &set),
            ("NEUSPIKE_RECORDING", &recording),
        ],
    );

    // What the Python package wrote: the same values, read by the Rust schemas.
    let read = |name: &str| {
        let bytes = std::fs::read(py.join(format!("{name}.arrow")))
            .unwrap_or_else(|e| panic!("python wrote {name}: {e}"));
        ipc::decode(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"))
    };
    let (urn, m, d) = read("frame");
    assert_eq!(urn, Frame::TYPE_URN);
    assert_eq!(Frame::from_arrow(&m, &d).expect("frame"), frame());
    let (urn, m, d) = read("representation");
    assert_eq!(urn, Representation::TYPE_URN);
    assert_eq!(
        Representation::from_arrow(&m, &d).expect("representation"),
        representation()
    );
    let (_, m, d) = read("spike_chunk");
    assert_eq!(
        SpikeChunk::from_arrow(&m, &d).expect("chunk"),
        spike_chunk()
    );
    let (_, m, d) = read("event_batch");
    assert_eq!(
        EventBatch::from_arrow(&m, &d).expect("batch"),
        event_batch()
    );
    let (_, m, d) = read("credit");
    assert_eq!(Credit::from_arrow(&m, &d).expect("credit"), credit());
    let (_, m, d) = read("end_of_stream");
    assert_eq!(neuspike_schemas::is_end_of_stream(&m), Some(17));
    assert!(m.flag("cut"));
    assert_eq!(d.len(), 0);
    assert_eq!(bad.len(), 20, "every damaged case was written");
}

/// The example Python node's own test: canned events, a stand-in for dora, no daemon.
#[test]
fn the_example_python_node_passes_its_unit_test() {
    if !python_has("pyarrow, numpy") {
        return;
    }
    python(
        &["-m", "unittest", "-v", "examples/python-node/test_node.py"],
        &[],
    );
}

fn read_png16(path: &Path) -> Vec<u16> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    img.into_luma16().into_raw()
}

/// The Python node in infer's place: every window becomes a scored frame, nothing lost, and its
/// frames equal the Rust example node's (the same gamma curve) to within one 16-bit level.
#[test]
fn a_users_python_node_takes_infers_place_and_agrees_with_the_rust_node() {
    if !python_has("pyarrow, numpy, dora") {
        return;
    }
    let run = |graph: &str| {
        let out = tempfile::tempdir().expect("tempdir");
        run_graph(
            graph,
            &[("sink", format!("--out {}", out.path().display()))],
        );
        out
    };
    let py = run("examples/python-node/graph.yml");
    let rust = run("examples/rust-node/graph.yml");
    let summary = std::fs::read_to_string(py.path().join("summary.md")).expect("summary");
    assert!(
        summary.contains("| gamma | 49 | 49 | 49 | 0 | yes |"),
        "{summary}"
    );
    let mut pngs: Vec<PathBuf> = std::fs::read_dir(py.path().join("gamma-py"))
        .expect("python frames")
        .map(|e| e.expect("entry").path())
        .collect();
    pngs.sort();
    assert_eq!(pngs.len(), 49);
    let mut worst = 0u16;
    for p in &pngs {
        let name = p.file_name().expect("name");
        let a = read_png16(p);
        let b = read_png16(&rust.path().join("gamma").join(name));
        assert_eq!(a.len(), b.len(), "{}", p.display());
        for (x, y) in a.iter().zip(&b) {
            worst = worst.max(x.abs_diff(*y));
        }
    }
    assert!(worst <= 1, "frames differ by {worst} 16-bit levels");
}

/// `graphs/view.yml`: the rerun viewer node, one entry in the live graph, records the frames (here
/// to a file, `--save`) while the sink still gets every frame: the viewer never holds the graph.
#[test]
fn the_rerun_viewer_node_shows_the_frames_without_holding_the_graph() {
    if !python_has("pyarrow, numpy, dora, rerun") {
        return;
    }
    let out = tempfile::tempdir().expect("tempdir");
    let rrd = out.path().join("run.rrd");
    run_graph(
        "graphs/view.yml",
        &[
            ("spike-source", "--max-planes 20000".into()),
            (
                "sink",
                format!("--out {}", out.path().join("sink").display()),
            ),
            ("view", format!("--save {}", rrd.display())),
        ],
    );
    let summary = std::fs::read_to_string(out.path().join("sink/summary.md")).expect("summary");
    assert!(summary.contains("| tfp | 199 | 199 |"), "{summary}");
    let printed = Command::new("python3")
        .args(["-m", "rerun", "rrd", "print"])
        .arg(&rrd)
        .output()
        .expect("rerun rrd print");
    assert!(printed.status.success(), "{printed:?}");
    let text = String::from_utf8_lossy(&printed.stdout);
    let mut chunks: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("Chunk(") && l.contains("/frames/tfp"))
        .collect();
    chunks.sort_unstable();
    chunks.dedup();
    let rows: usize = chunks
        .iter()
        .filter_map(|l| {
            l.split(" with ")
                .nth(1)?
                .split(" rows")
                .next()?
                .parse::<usize>()
                .ok()
        })
        .sum();
    assert!(
        rows > 0 && rows <= 199,
        "{rows} frames in the recording:\n{text}"
    );
}
