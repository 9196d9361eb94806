//! A message's header in and out of dora's metadata parameters.

use dora_node_api::{MetadataParameters, Parameter as DoraParameter};
use neuspike_schemas::{Meta, Parameter};

/// The header of a received message. Values of a kind no neuspike message uses (lists,
/// timestamps) become [`Parameter::Other`], described, so that a decoder's error can name them.
pub fn meta_from_dora(parameters: &MetadataParameters) -> Meta {
    parameters
        .iter()
        .map(|(k, v)| {
            let p = match v {
                DoraParameter::Bool(b) => Parameter::Bool(*b),
                DoraParameter::Integer(i) => Parameter::Integer(*i),
                DoraParameter::Float(f) => Parameter::Float(*f),
                DoraParameter::String(s) => Parameter::String(s.clone()),
                other => Parameter::Other(format!("{other:?}")),
            };
            (k.clone(), p)
        })
        .collect()
}

/// The metadata parameters of a message to send ([`Parameter::Other`] travels as its text).
pub fn meta_to_dora(meta: &Meta) -> MetadataParameters {
    meta.iter()
        .map(|(k, v)| {
            let p = match v {
                Parameter::Bool(b) => DoraParameter::Bool(*b),
                Parameter::Integer(i) => DoraParameter::Integer(*i),
                Parameter::Float(f) => DoraParameter::Float(*f),
                Parameter::String(s) | Parameter::Other(s) => DoraParameter::String(s.clone()),
            };
            (k.clone(), p)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_survive_the_round_trip() {
        let mut m = Meta::new();
        m.insert("a".into(), Parameter::Bool(true));
        m.insert("b".into(), Parameter::Integer(-7));
        m.insert("c".into(), Parameter::Float(0.25));
        m.insert("d".into(), Parameter::String("tfp".into()));
        assert_eq!(meta_from_dora(&meta_to_dora(&m)), m);
    }

    #[test]
    fn foreign_values_are_described() {
        let mut d = MetadataParameters::new();
        d.insert("list".into(), DoraParameter::ListInt(vec![1, 2]));
        match meta_from_dora(&d).get("list") {
            Some(Parameter::Other(s)) => assert!(s.contains("ListInt"), "{s}"),
            other => panic!("{other:?}"),
        }
    }
}
