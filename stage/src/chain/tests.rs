use super::*;
use crate::MsgType;
use neuspike_schemas::{Frame, FrameKind, SpikeChunk};
use std::sync::Mutex;

fn frame(seq: u64, value: f32) -> Frame {
    Frame {
        kind: FrameKind::Reconstruction,
        method: "test".into(),
        t_ref_ns: seq as i64,
        compute_ns: 0,
        chosen: None,
        budget_ns: None,
        seq,
        data: ndarray::Array2::from_elem((1, 2), value),
    }
}

/// Sends frames numbered `seqs`, then stops; fails at `fail_at` sends if set.
struct Source {
    seqs: Vec<u64>,
    next: usize,
    fail_at: Option<usize>,
    announce: Option<u64>,
}

impl Source {
    fn new(seqs: &[u64]) -> Self {
        Source {
            seqs: seqs.to_vec(),
            next: 0,
            fail_at: None,
            announce: None,
        }
    }
}

impl Stage for Source {
    fn name(&self) -> &str {
        "source"
    }
    fn inputs(&self) -> Vec<Port> {
        vec![]
    }
    fn outputs(&self) -> Vec<Port> {
        vec![Port::new("frames", MsgType::Frame)]
    }
    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        if self.fail_at == Some(self.next) {
            eyre::bail!("the camera broke");
        }
        let Some(&seq) = self.seqs.get(self.next) else {
            return Ok(Flow::Stop);
        };
        self.next += 1;
        out.send("frames", frame(seq, seq as f32));
        Ok(Flow::Continue)
    }
    fn on_message(&mut self, _: &str, _: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        Ok(Flow::Continue)
    }
    fn finish(&mut self, _: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        if let Some(n) = self.announce {
            out.at_least("frames", n);
        }
        Ok(())
    }
}

/// Doubles each frame's values; holds the last one back until its input ends.
struct Doubler {
    held: Option<Frame>,
    ended: Vec<(String, u64)>,
    finished_with: Option<Tallies>,
}

impl Doubler {
    fn new() -> Self {
        Doubler {
            held: None,
            ended: vec![],
            finished_with: None,
        }
    }
}

impl Stage for Doubler {
    fn name(&self) -> &str {
        "doubler"
    }
    fn inputs(&self) -> Vec<Port> {
        vec![Port::new("in", MsgType::Frame)]
    }
    fn outputs(&self) -> Vec<Port> {
        vec![Port::new("out", MsgType::Frame)]
    }
    fn on_message(&mut self, _: &str, msg: Msg, out: &mut Outbox) -> eyre::Result<Flow> {
        let mut f = Frame::try_from(msg)?;
        f.data *= 2.0;
        if let Some(prev) = self.held.replace(f) {
            out.send("out", prev);
        }
        Ok(Flow::Continue)
    }
    fn on_end(&mut self, input: &str, count: u64, _: &mut Outbox) -> eyre::Result<Flow> {
        self.ended.push((input.to_string(), count));
        Ok(Flow::Continue)
    }
    fn finish(&mut self, inputs: &Tallies, out: &mut Outbox) -> eyre::Result<()> {
        if let Some(f) = self.held.take() {
            out.send("out", f);
        }
        out.at_least("out", inputs.announced());
        self.finished_with = Some(inputs.clone());
        Ok(())
    }
}

/// Takes frames; reports what it saw at its end through `seen`.
struct Sink<'a> {
    seen: &'a Mutex<Vec<String>>,
}

impl Stage for Sink<'_> {
    fn name(&self) -> &str {
        "sink"
    }
    fn inputs(&self) -> Vec<Port> {
        vec![
            Port::new("a", MsgType::Frame),
            Port::new("b", MsgType::Frame),
        ]
    }
    fn outputs(&self) -> Vec<Port> {
        vec![]
    }
    fn on_message(&mut self, input: &str, msg: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        let f = Frame::try_from(msg)?;
        self.seen
            .lock()
            .expect("lock")
            .push(format!("{input}{}={}", f.seq, f.data[[0, 0]]));
        Ok(Flow::Continue)
    }
    fn on_end(&mut self, input: &str, count: u64, _: &mut Outbox) -> eyre::Result<Flow> {
        self.seen
            .lock()
            .expect("lock")
            .push(format!("{input} end {count}"));
        Ok(Flow::Continue)
    }
    fn finish(&mut self, inputs: &Tallies, _: &mut Outbox) -> eyre::Result<()> {
        for (id, t) in inputs.iter() {
            self.seen.lock().expect("lock").push(format!(
                "{id}: {} received, {} missing, cut {}",
                t.received, t.missing, t.cut
            ));
        }
        Ok(())
    }
}

#[test]
fn messages_go_through_in_order_and_every_end_carries_its_count() {
    let seen = Mutex::new(Vec::new());
    let mut tapped = Vec::new();
    let mut c = Chain::new();
    c.add("source", Source::new(&[0, 1, 2])).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.add("sink", Sink { seen: &seen }).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    c.connect("double/out", "sink/a").expect("wire");
    c.connect("source/frames", "sink/b").expect("wire");
    c.tap("double/out", |m| {
        tapped.push(Frame::try_from(m)?.seq);
        Ok(())
    })
    .expect("tap");
    let report = c.run().expect("run");
    assert_eq!(tapped, [0, 1, 2]);
    assert_eq!(
        *seen.lock().expect("lock"),
        [
            "b0=0",
            "b1=1",
            "a0=0",
            "b2=2",
            "a1=2",
            "b end 3",
            "a2=4",
            "a end 3",
            "a: 3 received, 0 missing, cut false",
            "b: 3 received, 0 missing, cut false"
        ]
    );
    assert_eq!(report.missing(), 0);
    let d = report.stage("double").expect("double");
    assert_eq!((d.received, d.sent, d.cut), (3, 3, false));
}

#[test]
fn a_gap_and_a_lost_tail_are_counted_downstream() {
    let seen = Mutex::new(Vec::new());
    let mut c = Chain::new();
    let mut s = Source::new(&[0, 2]);
    s.announce = Some(4); // 1 and 3 were never made
    c.add("source", s).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.add("sink", Sink { seen: &seen }).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    c.connect("double/out", "sink/a").expect("wire");
    c.connect("source/frames", "sink/b").expect("wire");
    let report = c.run().expect("run");
    let seen = seen.lock().expect("lock");
    assert!(seen.contains(&"a end 4".to_string()), "{seen:?}");
    assert!(
        seen.contains(&"a: 2 received, 2 missing, cut false".to_string()),
        "{seen:?}"
    );
    assert_eq!(report.missing(), 2 + 2 + 2);
}

#[test]
fn a_stage_that_fails_cuts_every_stream_after_it_and_the_run_fails_after_its_end() {
    let seen = Mutex::new(Vec::new());
    let mut c = Chain::new();
    let mut s = Source::new(&[0, 1, 2, 3]);
    s.fail_at = Some(2);
    c.add("source", s).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.add("sink", Sink { seen: &seen }).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    c.connect("double/out", "sink/a").expect("wire");
    c.connect("source/frames", "sink/b").expect("wire");
    let e = format!("{:#}", c.run().expect_err("failed"));
    assert!(
        e.contains("stage `source`") && e.contains("camera broke"),
        "{e}"
    );
    let seen = seen.lock().expect("lock");
    // What was made before the failure still arrives, then the cut ends.
    assert!(seen.contains(&"a1=2".to_string()), "{seen:?}");
    assert!(
        seen.contains(&"a: 2 received, 0 missing, cut true".to_string()),
        "{seen:?}"
    );
}

#[test]
fn a_wrong_edge_is_refused_naming_both_ends() {
    struct Spikes;
    impl Stage for Spikes {
        fn name(&self) -> &str {
            "spikes"
        }
        fn inputs(&self) -> Vec<Port> {
            vec![Port::new("spikes", MsgType::SpikeChunk)]
        }
        fn outputs(&self) -> Vec<Port> {
            vec![]
        }
        fn on_message(&mut self, _: &str, m: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
            SpikeChunk::try_from(m)?;
            Ok(Flow::Continue)
        }
    }
    let seen = Mutex::new(Vec::new());
    let mut c = Chain::new();
    c.add("source", Source::new(&[0])).expect("add");
    c.add("spikes", Spikes).expect("add");
    c.add("sink", Sink { seen: &seen }).expect("add");
    let err = |r: eyre::Result<&mut Chain<'_>>| r.err().map(|e| e.to_string()).unwrap_or_default();
    assert_eq!(
        err(c.connect("source/frames", "spikes/spikes")),
        "chain: `source/frames` sends Frame but `spikes/spikes` reads SpikeChunk"
    );
    assert_eq!(
        err(c.connect("source/frame", "sink/a")),
        "chain: stage `source` has no output `frame` (it has: frames)"
    );
    assert_eq!(
        err(c.connect("camera/frames", "sink/a")),
        "chain: no stage `camera`"
    );
    assert_eq!(
        err(c.add("sink", Doubler::new())),
        "chain: stage id `sink` is used twice"
    );
    c.connect("source/frames", "sink/a").expect("wire");
    assert_eq!(
        err(c.connect("source/frames", "sink/a")),
        "chain: `sink/a` is fed twice: by `source/frames` and by `source/frames`"
    );
    let e = c.run().expect_err("unfed").to_string();
    assert!(
        e.contains("`spikes/spikes` (SpikeChunk) is fed by no stage"),
        "{e}"
    );
}

/// Drives `stage` as a driver would: steps a source until it stops, else hands it `feed` and
/// then each input's end; returns what it sent (output, seq) and the counts it announced.
/// What a driven stage sent (output, seq), the counts it announced, and whether it was cut.
type Driven = (Vec<(String, u64)>, Vec<(String, u64)>, bool);

fn drive(stage: &mut dyn Stage, feed: Vec<(&str, Msg)>) -> Driven {
    let mut out = Outbox::new();
    let mut sent = Vec::new();
    let take = |out: &mut Outbox, sent: &mut Vec<(String, u64)>| {
        for s in out.take_sent() {
            sent.push((s.output, s.msg.seq()));
        }
    };
    if stage.inputs().is_empty() {
        while stage.step(&mut out).expect("step") == Flow::Continue {
            take(&mut out, &mut sent);
        }
        take(&mut out, &mut sent);
    } else {
        let n = feed.len() as u64;
        for (input, msg) in feed {
            stage.on_message(input, msg, &mut out).expect("message");
            take(&mut out, &mut sent);
        }
        for p in stage.inputs() {
            stage.on_end(&p.id, n, &mut out).expect("end");
            take(&mut out, &mut sent);
        }
    }
    stage.finish(&Tallies::default(), &mut out).expect("finish");
    take(&mut out, &mut sent);
    let counts = out.take_at_least().collect();
    (sent, counts, out.take_cut())
}

#[test]
fn a_fused_chain_is_one_stage_whose_ports_are_its_inlets_and_outlets() {
    let mut c = Chain::new();
    c.add("double", Doubler::new()).expect("add");
    c.add("again", Doubler::new()).expect("add");
    c.connect("double/out", "again/in").expect("wire");
    c.inlet("frames", "double/in").expect("inlet");
    c.outlet("doubled", "double/out").expect("outlet");
    c.outlet("quadrupled", "again/out").expect("outlet");
    let mut f = c.into_stage("core").expect("stage");
    assert_eq!(f.inputs(), [Port::new("frames", MsgType::Frame)]);
    assert_eq!(
        f.outputs(),
        [
            Port::new("doubled", MsgType::Frame),
            Port::new("quadrupled", MsgType::Frame)
        ]
    );
    let feed = (0..3)
        .map(|i| ("frames", Msg::from(frame(i, 1.0))))
        .collect();
    let (sent, counts, cut) = drive(&mut f, feed);
    let of = |o: &str| -> Vec<u64> {
        sent.iter()
            .filter(|(n, _)| n == o)
            .map(|(_, s)| *s)
            .collect()
    };
    assert_eq!(of("doubled"), [0, 1, 2]);
    assert_eq!(of("quadrupled"), [0, 1, 2]);
    assert!(counts.contains(&("doubled".to_string(), 3)), "{counts:?}");
    assert!(
        counts.contains(&("quadrupled".to_string(), 3)),
        "{counts:?}"
    );
    assert!(!cut);
    let report = f.report().expect("report");
    assert_eq!(
        report.stage("again").map(|s| (s.received, s.sent)),
        Some((3, 3))
    );
    assert_eq!(report.missing(), 0);
}

#[test]
fn a_fused_chain_with_a_source_runs_it_on_a_thread_and_loses_nothing() {
    let seen: &'static Mutex<Vec<String>> = Box::leak(Box::new(Mutex::new(Vec::new())));
    let mut c = Chain::new();
    let seqs: Vec<u64> = (0..500).collect();
    c.add("source", Source::new(&seqs)).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.add("sink", Sink { seen }).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    c.connect("double/out", "sink/a").expect("wire");
    c.connect("source/frames", "sink/b").expect("wire");
    c.outlet("doubled", "double/out").expect("outlet");
    let mut f = c.into_stage("all").expect("stage");
    assert!(f.inputs().is_empty());
    let (sent, counts, cut) = drive(&mut f, Vec::new());
    let seqs_out: Vec<u64> = sent.iter().map(|(_, s)| *s).collect();
    assert_eq!(seqs_out, seqs);
    assert_eq!(counts, [("doubled".to_string(), 500)]);
    assert!(!cut);
    let seen = seen.lock().expect("lock");
    assert!(
        seen.contains(&"a: 500 received, 0 missing, cut false".to_string()),
        "{:?}",
        &seen[seen.len().saturating_sub(3)..]
    );
    let report = f.report().expect("report");
    assert_eq!(report.stage("source").map(|s| s.sent), Some(500));
}

#[test]
fn a_failing_source_on_a_thread_cuts_the_fused_stage_after_sending_what_it_made() {
    let mut c = Chain::new();
    let mut s = Source::new(&[0, 1, 2, 3]);
    s.fail_at = Some(2);
    c.add("source", s).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    c.outlet("doubled", "double/out").expect("outlet");
    let mut f = c.into_stage("all").expect("stage");
    let mut out = Outbox::new();
    while f.step(&mut out).expect("step") == Flow::Continue {}
    let e = format!(
        "{:#}",
        f.finish(&Tallies::default(), &mut out).expect_err("failed")
    );
    assert!(
        e.contains("fused stage `all`") && e.contains("camera broke"),
        "{e}"
    );
    let seqs: Vec<u64> = out.take_sent().map(|s| s.msg.seq()).collect();
    assert_eq!(seqs, [0, 1]);
    assert!(out.take_cut());
}

#[test]
fn a_fused_chain_is_refused_when_its_ports_do_not_fit() {
    let mut c = Chain::new();
    c.add("source", Source::new(&[0])).expect("add");
    c.add("double", Doubler::new()).expect("add");
    c.add("again", Doubler::new()).expect("add");
    c.connect("source/frames", "double/in").expect("wire");
    let e = c
        .inlet("more", "double/in")
        .err()
        .expect("fed twice")
        .to_string();
    assert_eq!(
        e,
        "chain: `double/in` is fed twice: by `source/frames` and by inlet `more`"
    );
    c.inlet("frames", "again/in").expect("inlet");
    let e = c
        .into_stage("x")
        .err()
        .expect("source and inlet")
        .to_string();
    assert!(
        e.contains("takes no input from outside (it has `frames`)"),
        "{e}"
    );
    let mut c = Chain::new();
    c.add("double", Doubler::new()).expect("add");
    let e = c.run().err();
    assert!(e.is_some());
    let mut c = Chain::new();
    c.add("double", Doubler::new()).expect("add");
    c.inlet("frames", "double/in").expect("inlet");
    let e = c.run().expect_err("inlet").to_string();
    assert!(
        e.contains("inlet `frames` takes messages from outside"),
        "{e}"
    );
}

/// Takes frames on its own thread (it has no outputs); fails on the frame numbered `fail_at`.
struct FailingSink {
    fail_at: u64,
    seen: &'static Mutex<Vec<u64>>,
}

impl Stage for FailingSink {
    fn name(&self) -> &str {
        "failing-sink"
    }
    fn inputs(&self) -> Vec<Port> {
        vec![Port::new("a", MsgType::Frame)]
    }
    fn outputs(&self) -> Vec<Port> {
        vec![]
    }
    fn on_message(&mut self, _: &str, msg: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        let f = Frame::try_from(msg)?;
        if f.seq == self.fail_at {
            eyre::bail!("the disk is full");
        }
        self.seen.lock().expect("lock").push(f.seq);
        Ok(Flow::Continue)
    }
}

#[test]
fn a_sink_on_a_thread_that_fails_fails_the_fused_stage_naming_it_and_takes_nothing_after() {
    let seen: &'static Mutex<Vec<u64>> = Box::leak(Box::new(Mutex::new(Vec::new())));
    let mut c = Chain::new();
    let seqs: Vec<u64> = (0..200).collect();
    c.add("source", Source::new(&seqs)).expect("add");
    c.add("sink", FailingSink { fail_at: 50, seen })
        .expect("add");
    c.connect("source/frames", "sink/a").expect("wire");
    let mut f = c.into_stage("all").expect("stage");
    let mut out = Outbox::new();
    while f.step(&mut out).expect("step") == Flow::Continue {}
    let e = format!(
        "{:#}",
        f.finish(&Tallies::default(), &mut out).expect_err("failed")
    );
    assert!(
        e.contains("fused stage `all`") && e.contains("stage `sink`") && e.contains("disk is full"),
        "{e}"
    );
    // Every frame before the failure, none after.
    assert_eq!(*seen.lock().expect("lock"), (0..50).collect::<Vec<_>>());
    let report = f.report().expect("report");
    assert!(report.stage("sink").is_some_and(|s| s.cut));
}
