//! Every stage by name, made from its node's arguments and wiring.

use clap::Parser;
use eyre::{WrapErr, eyre};
use neuspike_align::{AlignConfig, AlignStage};
use neuspike_event_camera::playback::{EventSource, EventSourceConfig, EventSourceStage};
use neuspike_reconstruction::{InferConfig, InferStage};
use neuspike_representations::{RepresentConfig, RepresentStage, Representer};
use neuspike_schemas::RepresentationKind;
use neuspike_sink::{SinkConfig, SinkStage};
use neuspike_spike_camera::playback::{SpikeSource, SpikeSourceConfig, SpikeSourceStage};
use neuspike_stage::{Pace, Pacer, Stage};

/// The stages [`make_stage`] makes, by the name their node binaries carry after `neuspike-`.
pub const STAGES: [&str; 6] = [
    "spike-source",
    "event-source",
    "align",
    "represent",
    "infer",
    "sink",
];

/// The stage a node binary runs: `neuspike-align` (or a path to it, `.exe` or not) is `align`.
pub fn stage_kind(path: &str) -> Option<&'static str> {
    let file = path.rsplit(['/', '\\']).next().unwrap_or(path);
    let file = file.strip_suffix(".exe").unwrap_or(file);
    let name = file.strip_prefix("neuspike-")?;
    STAGES.into_iter().find(|s| *s == name)
}

#[derive(Debug, Parser)]
#[command(
    name = "spike-source",
    args_override_self = true,
    no_binary_name = true
)]
struct SpikeSourceArgs {
    #[command(flatten)]
    source: SpikeSourceConfig,
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
}

#[derive(Debug, Parser)]
#[command(
    name = "event-source",
    args_override_self = true,
    no_binary_name = true
)]
struct EventSourceArgs {
    #[command(flatten)]
    source: EventSourceConfig,
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
}

#[derive(Debug, Parser)]
#[command(name = "align", args_override_self = true, no_binary_name = true)]
struct AlignArgs {
    #[command(flatten)]
    align: AlignConfig,
}

#[derive(Debug, Parser)]
#[command(name = "represent", args_override_self = true, no_binary_name = true)]
struct RepresentArgs {
    #[command(flatten)]
    represent: RepresentConfig,
}

#[derive(Debug, Parser)]
#[command(name = "infer", args_override_self = true, no_binary_name = true)]
struct InferArgs {
    #[command(flatten)]
    infer: InferConfig,
}

#[derive(Debug, Parser)]
#[command(name = "sink", args_override_self = true, no_binary_name = true)]
struct SinkArgs {
    #[command(flatten)]
    sink: SinkConfig,
}

fn parse<P: Parser>(kind: &str, args: &[String]) -> eyre::Result<P> {
    P::try_parse_from(args).map_err(|e| {
        let e = e.to_string();
        let first = e
            .lines()
            .next()
            .unwrap_or_default()
            .trim_start_matches("error: ");
        eyre!("{kind}: bad arguments `{}`: {first}", args.join(" "))
    })
}

/// Makes stage `kind` (one of [`STAGES`]) from `args` (its node's `args:`, split into words) and
/// the ids of the `inputs` and `outputs` the graph gives it, as its node binary does: `infer`
/// reads the inputs its method needs, `represent` computes the kinds among its outputs, `align`
/// reads events and streams them when wired so, `sink` reads every input.
///
/// # Errors
/// An unknown stage, arguments it does not take (one line naming the stage and the argument), or
/// a setting the stage refuses (a scene or file that cannot be opened, a network that does not
/// load).
pub fn make_stage(
    kind: &str,
    args: &[String],
    inputs: &[String],
    outputs: &[String],
) -> eyre::Result<Box<dyn Stage>> {
    let has = |ids: &[String], id: &str| ids.iter().any(|i| i == id);
    Ok(match kind {
        "spike-source" => {
            let a: SpikeSourceArgs = parse(kind, args)?;
            let source = SpikeSource::open(&a.source).wrap_err(kind.to_string())?;
            source.log_start();
            Box::new(SpikeSourceStage::new(source, Pacer::start(a.pace)))
        }
        "event-source" => {
            let a: EventSourceArgs = parse(kind, args)?;
            let source = EventSource::open(&a.source).wrap_err(kind.to_string())?;
            source.log_start();
            Box::new(EventSourceStage::new(source, Pacer::start(a.pace)))
        }
        "align" => {
            let a: AlignArgs = parse(kind, args)?;
            Box::new(AlignStage::new(
                a.align,
                has(inputs, "events"),
                has(outputs, "events"),
            ))
        }
        "represent" => {
            let a: RepresentArgs = parse(kind, args)?;
            let representer = Representer::new(a.represent).map_err(|e| eyre!("represent: {e}"))?;
            let kinds: Vec<RepresentationKind> = RepresentationKind::ALL
                .into_iter()
                .filter(|k| has(outputs, k.name()))
                .collect();
            Box::new(RepresentStage::new(representer, &kinds))
        }
        "infer" => {
            let a: InferArgs = parse(kind, args)?;
            let r = a
                .infer
                .reconstructor(inputs)
                .map_err(|e| eyre!("infer: {e}"))?;
            Box::new(InferStage::new(r))
        }
        "sink" => {
            let a: SinkArgs = parse(kind, args)?;
            Box::new(SinkStage::new(&a.sink, inputs).wrap_err("sink")?)
        }
        other => {
            return Err(eyre!(
                "`{other}` is not a neuspike stage (the stages: {})",
                STAGES.join(", ")
            ));
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &str) -> Vec<String> {
        s.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn a_node_binary_names_its_stage() {
        assert_eq!(
            stage_kind("../target/release/neuspike-align"),
            Some("align")
        );
        assert_eq!(stage_kind("C:\\bin\\neuspike-sink.exe"), Some("sink"));
        assert_eq!(stage_kind("neuspike-infer"), Some("infer"));
        assert_eq!(stage_kind("python3"), None);
        assert_eq!(stage_kind("neuspike-example-node"), None);
    }

    #[test]
    fn a_stage_is_made_with_the_ports_its_wiring_asks_for() {
        let none: [String; 0] = [];
        let r = make_stage(
            "represent",
            &words("--tfp-planes 33"),
            &words("windows"),
            &words("tfp isi credits"),
        )
        .expect("represent");
        let outs: Vec<String> = r.outputs().into_iter().map(|p| p.id).collect();
        assert_eq!(outs, ["tfp", "isi"]);
        let a = make_stage("align", &none, &words("spikes"), &words("windows")).expect("align");
        assert_eq!(a.inputs().len(), 1);
        let a = make_stage(
            "align",
            &none,
            &words("spikes events"),
            &words("windows events"),
        )
        .expect("align");
        assert_eq!((a.inputs().len(), a.outputs().len()), (2, 2));
        let i = make_stage(
            "infer",
            &words("--method tfi"),
            &words("representation"),
            &none,
        )
        .expect("infer");
        assert_eq!(i.inputs()[0].id, "representation");
    }

    #[test]
    fn bad_arguments_are_one_line_naming_the_stage() {
        let e = make_stage("align", &words("--window-planes x"), &[], &[])
            .err()
            .expect("refused")
            .to_string();
        assert!(
            e.starts_with("align: bad arguments `--window-planes x`:"),
            "{e}"
        );
        assert!(!e.contains('\n'), "{e}");
        let e = make_stage("camera", &[], &[], &[])
            .err()
            .expect("unknown")
            .to_string();
        assert!(e.contains("`camera` is not a neuspike stage"), "{e}");
    }
}
