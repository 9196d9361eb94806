//! Settings given as a Python dict, parsed by the command-line definitions they mirror (a node's
//! arguments, `neuspike dataset`'s options), so that every setting is there under the same name
//! and is refused with the same message.

use clap::{ArgAction, CommandFactory, Parser};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict};

use crate::errors;

/// A dict as the command-line words of `P`: `{"fpn_mu": 150}` is `--fpn-mu=150`; a switch
/// (`{"randomise_camera": True}`) is `--randomise-camera` when true and left out when false.
pub fn flags<P: CommandFactory>(
    what: &str,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<Vec<String>> {
    let mut out = Vec::new();
    let Some(settings) = settings else {
        return Ok(out);
    };
    let command = P::command();
    for (k, v) in settings.iter() {
        let key: String = k.extract().map_err(|_| {
            errors::config(format!(
                "{what}: a setting's name must be a string, got {k}"
            ))
        })?;
        let long = key.replace('_', "-");
        let switch = command
            .get_arguments()
            .find(|a| a.get_long() == Some(long.as_str()))
            .is_some_and(|a| matches!(a.get_action(), ArgAction::SetTrue));
        if v.is_instance_of::<PyBool>() {
            let on = v.is_truthy()?;
            match (switch, on) {
                (true, true) => out.push(format!("--{long}")),
                (true, false) => {}
                (false, on) => out.push(format!("--{long}={on}")),
            }
        } else if v.is_none() {
            continue;
        } else if let Ok(items) = v.extract::<Vec<Bound<'_, PyAny>>>()
            && !v.is_instance_of::<pyo3::types::PyString>()
        {
            let words = items
                .iter()
                .map(|i| i.str().map(|s| s.to_string()))
                .collect::<PyResult<Vec<_>>>()?;
            out.push(format!("--{long}={}", words.join(",")));
        } else {
            out.push(format!("--{long}={}", v.str()?));
        }
    }
    Ok(out)
}

/// Parses words as `P`; the refusal is one line naming `what`.
pub fn parse<P: Parser>(what: &str, args: &[String]) -> PyResult<P> {
    P::try_parse_from(args).map_err(|e| {
        let text = e.to_string();
        let first = text
            .lines()
            .next()
            .unwrap_or_default()
            .trim_start_matches("error: ")
            .to_owned();
        errors::config(format!("{what}: {first}"))
    })
}
