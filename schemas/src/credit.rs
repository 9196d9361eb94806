//! Credits: how a consumer tells its producers how many more messages it can take.
//!
//! neuspike's flow control over dora's zero-copy path: a consumer grants each input as many
//! credits as its queue holds, and returns one for every message it has taken off that queue; a
//! producer sends a message only while every consumer of that output has a credit left. No queue
//! then ever overflows, so nothing is dropped, and no message takes the daemon's copying path.

use std::sync::Arc;

use arrow::array::{Array, ArrayRef, StringArray, StructArray, UInt64Array};
use arrow::datatypes::{DataType, Field, Fields};

use crate::Message;
use crate::meta::{self, Meta, SchemaError, check_type};

/// Metadata key of a consumer's first credit message, which lists every input it grants.
pub const HELLO: &str = "hello";

/// Credits one consumer returns: for each of its inputs, named by its source (`node/output`),
/// the messages it can take more. The first message a consumer sends (`hello`) lists every
/// input it flow-controls with its whole window, so that a producer knows which of its outputs
/// each consumer reads before its first send.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Credit {
    /// The consumer's first message: its inputs and their windows.
    pub hello: bool,
    /// `(source, credits)`: `source` is `node/output` as the consumer's graph entry names it.
    pub grants: Vec<(String, u64)>,
}

impl Credit {
    fn fields() -> Fields {
        Fields::from(vec![
            Field::new("source", DataType::Utf8, false),
            Field::new("credits", DataType::UInt64, false),
        ])
    }
}

impl Message for Credit {
    const TYPE_URN: &'static str = "neuspike/messages/v1/Credit";

    fn data_type() -> DataType {
        DataType::Struct(Self::fields())
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        let mut m = Meta::new();
        m.insert(HELLO.to_string(), meta::Parameter::Bool(self.hello));
        let sources = StringArray::from_iter_values(self.grants.iter().map(|(s, _)| s.as_str()));
        let credits = UInt64Array::from_iter_values(self.grants.iter().map(|&(_, c)| c));
        let cols: Vec<ArrayRef> = vec![Arc::new(sources), Arc::new(credits)];
        (m, Arc::new(StructArray::new(Self::fields(), cols, None)))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        const MESSAGE: &str = "credit";
        check_type(MESSAGE, &Self::data_type(), data.data_type())?;
        let bad = |what: String| SchemaError::Inconsistent {
            message: MESSAGE,
            what,
        };
        let s = data
            .as_any()
            .downcast_ref::<StructArray>()
            .ok_or_else(|| bad("payload is not a struct array".into()))?;
        let sources = s
            .column_by_name("source")
            .and_then(|c| c.as_any().downcast_ref::<StringArray>())
            .ok_or_else(|| bad("no Utf8 column `source`".into()))?;
        let credits = s
            .column_by_name("credits")
            .and_then(|c| c.as_any().downcast_ref::<UInt64Array>())
            .ok_or_else(|| bad("no UInt64 column `credits`".into()))?;
        if s.null_count() + sources.null_count() + credits.null_count() != 0 {
            return Err(bad("a grant is null".into()));
        }
        let grants = sources
            .iter()
            .zip(credits.iter())
            .map(|(s, c)| (s.unwrap_or_default().to_string(), c.unwrap_or(0)))
            .collect();
        use crate::MetaExt;
        Ok(Credit {
            hello: m.flag(HELLO),
            grants,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn credits_round_trip_and_a_wrong_payload_is_named() {
        let c = Credit {
            hello: true,
            grants: vec![("align/windows".into(), 16), ("align/events".into(), 4)],
        };
        let (m, data) = c.to_arrow();
        assert_eq!(Credit::from_arrow(&m, &data), Ok(c));
        let more = Credit {
            hello: false,
            grants: vec![("src/out".into(), 8)],
        };
        let (m, data) = more.to_arrow();
        assert_eq!(Credit::from_arrow(&m, &data), Ok(more));
        let wrong: ArrayRef = Arc::new(UInt64Array::from(vec![1u64]));
        let e = Credit::from_arrow(&m, &wrong).expect_err("a plain array");
        assert!(
            e.to_string().starts_with("credit: payload has Arrow type"),
            "{e}"
        );
    }
}
