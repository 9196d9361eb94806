//! Event batches: DVS events over a half-open time interval.

use std::sync::Arc;

use arrow::array::{Array, ArrayRef, Int8Array, Int64Array, StructArray, UInt16Array};
use arrow::datatypes::{DataType, Field, Fields};

use crate::Message;
use crate::meta::{self, Meta, MetaExt, SchemaError, check_type, int_of};

const NAME: &str = "event batch";

/// One DVS event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Event {
    /// Timestamp in nanoseconds.
    pub t_ns: i64,
    /// Column, `0..width`.
    pub x: u16,
    /// Row, `0..height`, top-down.
    pub y: u16,
    /// +1 (ON, brighter) or -1 (OFF, darker).
    pub polarity: i8,
}

/// The events of the half-open interval `[t_start_ns, t_end_ns)`, sorted by time, as columns.
/// An empty batch is legal and says "no events in this interval".
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct EventBatch {
    /// Sensor width in pixels.
    pub width: usize,
    /// Sensor height in pixels.
    pub height: usize,
    /// Start of the interval covered (inclusive), nanoseconds.
    pub t_start_ns: i64,
    /// End of the interval covered (exclusive), nanoseconds.
    pub t_end_ns: i64,
    /// Sequence number on its output.
    pub seq: u64,
    /// Timestamps, non-decreasing, inside the interval.
    pub t_ns: Vec<i64>,
    /// Columns.
    pub x: Vec<u16>,
    /// Rows.
    pub y: Vec<u16>,
    /// Polarities, +1 or -1.
    pub polarity: Vec<i8>,
}

impl EventBatch {
    /// An empty batch covering `[t_start_ns, t_end_ns)`.
    pub fn empty(width: usize, height: usize, t_start_ns: i64, t_end_ns: i64, seq: u64) -> Self {
        EventBatch {
            width,
            height,
            t_start_ns,
            t_end_ns,
            seq,
            ..Default::default()
        }
    }

    /// Number of events.
    #[inline]
    pub fn len(&self) -> usize {
        self.t_ns.len()
    }

    /// Whether the batch holds no event.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.t_ns.is_empty()
    }

    /// Appends one event (the caller keeps time order).
    #[inline]
    pub fn push(&mut self, e: Event) {
        self.t_ns.push(e.t_ns);
        self.x.push(e.x);
        self.y.push(e.y);
        self.polarity.push(e.polarity);
    }

    /// Keeps the first `len` events (all of them when there are fewer).
    pub fn truncate(&mut self, len: usize) {
        self.t_ns.truncate(len);
        self.x.truncate(len);
        self.y.truncate(len);
        self.polarity.truncate(len);
    }

    /// Sets every column to `len` entries, cutting or padding with zeros. A padded entry (polarity
    /// 0) is no event: it is room for a decoder to write by index, and it must be overwritten or
    /// cut before the batch is used.
    pub fn resize(&mut self, len: usize) {
        self.t_ns.resize(len, 0);
        self.x.resize(len, 0);
        self.y.resize(len, 0);
        self.polarity.resize(len, 0);
    }

    /// Event `i`.
    #[inline]
    pub fn get(&self, i: usize) -> Event {
        Event {
            t_ns: self.t_ns[i],
            x: self.x[i],
            y: self.y[i],
            polarity: self.polarity[i],
        }
    }

    /// The Arrow fields of one event.
    pub fn event_fields() -> Fields {
        Fields::from(vec![
            Field::new("t_ns", DataType::Int64, false),
            Field::new("x", DataType::UInt16, false),
            Field::new("y", DataType::UInt16, false),
            Field::new("polarity", DataType::Int8, false),
        ])
    }

    /// The columns as an Arrow struct array.
    pub fn to_struct_array(&self) -> StructArray {
        let cols: Vec<ArrayRef> = vec![
            Arc::new(Int64Array::from(self.t_ns.clone())),
            Arc::new(UInt16Array::from(self.x.clone())),
            Arc::new(UInt16Array::from(self.y.clone())),
            Arc::new(Int8Array::from(self.polarity.clone())),
        ];
        StructArray::new(Self::event_fields(), cols, None)
    }

    /// Reads the event columns of a struct array and checks every event against the sensor size
    /// and the interval. Errors name the event index and the value.
    pub fn fill_from_struct(
        &mut self,
        message: &'static str,
        s: &StructArray,
    ) -> Result<(), SchemaError> {
        let col = |name: &str| {
            s.column_by_name(name)
                .ok_or_else(|| SchemaError::Inconsistent {
                    message,
                    what: format!("event column `{name}` is missing"),
                })
        };
        let bad = |name: &str, found: &DataType| SchemaError::BadType {
            message,
            expected: format!("event column `{name}`"),
            found: found.to_string(),
        };
        let t = col("t_ns")?;
        let t = t
            .as_any()
            .downcast_ref::<Int64Array>()
            .ok_or_else(|| bad("t_ns Int64", t.data_type()))?;
        let x = col("x")?;
        let x = x
            .as_any()
            .downcast_ref::<UInt16Array>()
            .ok_or_else(|| bad("x UInt16", x.data_type()))?;
        let y = col("y")?;
        let y = y
            .as_any()
            .downcast_ref::<UInt16Array>()
            .ok_or_else(|| bad("y UInt16", y.data_type()))?;
        let p = col("polarity")?;
        let p = p
            .as_any()
            .downcast_ref::<Int8Array>()
            .ok_or_else(|| bad("polarity Int8", p.data_type()))?;
        if s.null_count() + t.null_count() + x.null_count() + y.null_count() + p.null_count() != 0 {
            return Err(SchemaError::Inconsistent {
                message,
                what: "events contain nulls".into(),
            });
        }
        self.t_ns = t.values().to_vec();
        self.x = x.values().to_vec();
        self.y = y.values().to_vec();
        self.polarity = p.values().to_vec();
        self.validate(message)
    }

    /// Checks coordinates, polarities, order and interval. Errors name the event index and value.
    pub fn validate(&self, message: &'static str) -> Result<(), SchemaError> {
        let err = |what: String| Err(SchemaError::Inconsistent { message, what });
        if self.t_end_ns < self.t_start_ns {
            return err(format!(
                "interval [{}, {}) ends before it starts",
                self.t_start_ns, self.t_end_ns
            ));
        }
        let n = self.t_ns.len();
        if self.x.len() != n || self.y.len() != n || self.polarity.len() != n {
            return err("event columns differ in length".into());
        }
        let mut prev = i64::MIN;
        for i in 0..n {
            let e = self.get(i);
            if usize::from(e.x) >= self.width || usize::from(e.y) >= self.height {
                return err(format!(
                    "event {i} at ({}, {}) is outside the {}x{} sensor",
                    e.x, e.y, self.width, self.height
                ));
            }
            if e.polarity != 1 && e.polarity != -1 {
                return err(format!(
                    "event {i} has polarity {}, expected +1 or -1",
                    e.polarity
                ));
            }
            if e.t_ns < prev {
                return err(format!(
                    "event {i} at t_ns {} is earlier than event {} at {prev}",
                    e.t_ns,
                    i - 1
                ));
            }
            if e.t_ns < self.t_start_ns || e.t_ns >= self.t_end_ns {
                return err(format!(
                    "event {i} at t_ns {} is outside the batch interval [{}, {})",
                    e.t_ns, self.t_start_ns, self.t_end_ns
                ));
            }
            prev = e.t_ns;
        }
        Ok(())
    }
}

impl Message for EventBatch {
    const TYPE_URN: &'static str = "neuspike/messages/v1/EventBatch";

    fn data_type() -> DataType {
        DataType::Struct(Self::event_fields())
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        let mut m = Meta::new();
        m.set_int(meta::WIDTH, int_of(self.width));
        m.set_int(meta::HEIGHT, int_of(self.height));
        m.set_int(meta::T_START_NS, self.t_start_ns);
        m.set_int(meta::T_END_NS, self.t_end_ns);
        m.set_int(meta::SEQ, self.seq as i64);
        (m, Arc::new(self.to_struct_array()))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        check_type(NAME, &Self::data_type(), data.data_type())?;
        let mut b = EventBatch {
            width: m.size(NAME, meta::WIDTH)?,
            height: m.size(NAME, meta::HEIGHT)?,
            t_start_ns: m.int(NAME, meta::T_START_NS)?,
            t_end_ns: m.int(NAME, meta::T_END_NS)?,
            seq: m.uint(NAME, meta::SEQ)?,
            ..Default::default()
        };
        // 0 x 0: a batch without an event camera (align's windows without one).
        if (b.width, b.height) != (0, 0) {
            crate::limits::check_sensor(NAME, b.width, b.height)?;
        }
        let s =
            data.as_any()
                .downcast_ref::<StructArray>()
                .ok_or_else(|| SchemaError::BadType {
                    message: NAME,
                    expected: "Struct".into(),
                    found: data.data_type().to_string(),
                })?;
        b.fill_from_struct(NAME, s)?;
        Ok(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch() -> EventBatch {
        let mut b = EventBatch::empty(346, 260, 1_000, 2_000, 4);
        b.push(Event {
            t_ns: 1_000,
            x: 0,
            y: 0,
            polarity: 1,
        });
        b.push(Event {
            t_ns: 1_500,
            x: 345,
            y: 259,
            polarity: -1,
        });
        b
    }

    #[test]
    fn a_batch_claiming_a_huge_sensor_is_refused_before_anything_is_made() {
        let (mut m, a) = EventBatch::empty(346, 260, 0, 10, 0).to_arrow();
        m.set_int(meta::WIDTH, 65_535);
        m.set_int(meta::HEIGHT, 65_535);
        let e = EventBatch::from_arrow(&m, &a).unwrap_err().to_string();
        assert!(e.starts_with("event batch: sensor 65535x65535 has"), "{e}");
        // No camera: the empty 0 x 0 batch still passes.
        let (m, a) = EventBatch::empty(0, 0, 0, 10, 0).to_arrow();
        assert!(EventBatch::from_arrow(&m, &a).is_ok());
    }

    #[test]
    fn round_trip_and_empty() {
        let b = batch();
        let (m, a) = b.to_arrow();
        assert_eq!(EventBatch::from_arrow(&m, &a).unwrap(), b);
        let e = EventBatch::empty(2, 2, 0, 10, 0);
        let (m, a) = e.to_arrow();
        assert!(EventBatch::from_arrow(&m, &a).unwrap().is_empty());
    }

    #[test]
    fn bad_events_are_named() {
        let mut b = batch();
        b.x[1] = 346;
        assert!(
            b.validate(NAME)
                .unwrap_err()
                .to_string()
                .contains("event 1 at (346, 259)")
        );
        let mut b = batch();
        b.polarity[0] = 0;
        assert!(
            b.validate(NAME)
                .unwrap_err()
                .to_string()
                .contains("polarity 0")
        );
        let mut b = batch();
        b.t_ns[1] = 999;
        assert!(b.validate(NAME).unwrap_err().to_string().contains("999"));
        let mut b = batch();
        b.t_ns[1] = 2_000;
        assert!(
            b.validate(NAME)
                .unwrap_err()
                .to_string()
                .contains("outside the batch interval")
        );
    }
}
