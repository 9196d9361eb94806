//! The one error type of this crate.

/// Why a representation kernel refused its inputs.
///
/// Every message names the argument that was wrong and the value it had, so that a node can log
/// it as is.
#[derive(Debug, thiserror::Error)]
pub enum RepresentError {
    /// An array's shape does not fit the kernel or the other arguments.
    #[error("{what}: expected shape {expected}, got {actual}")]
    Shape {
        /// Which argument (and which axis, where it matters).
        what: &'static str,
        /// The shape the kernel needed, written out (`[32, 250, 400]`, `[K = 3, ..]`).
        expected: String,
        /// The shape it was given.
        actual: String,
    },
    /// An index (a reference plane, an event's coordinate) lies outside its range.
    #[error("{what} = {value} is out of range (must be < {limit})")]
    Index {
        /// What the index is, with the event number where there is one (`x of event 17`).
        what: String,
        /// The offending value.
        value: u64,
        /// The exclusive upper bound it had to respect.
        limit: u64,
    },
    /// A scalar parameter or an ordering requirement is violated.
    #[error("{name} = {value}: {reason}")]
    Param {
        /// The parameter's name.
        name: &'static str,
        /// Its value, written out (with the position where it is an element of a slice).
        value: String,
        /// What it had to satisfy.
        reason: &'static str,
    },
}

/// Writes a shape as `[a, b, c]` for error messages.
pub(crate) fn shape_str(shape: &[usize]) -> String {
    format!("{shape:?}")
}
