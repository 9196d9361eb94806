//! The one error type of the crate: every variant names the file, where in it (byte offset or line
//! number) and the value that was wrong.

use std::fmt;
use std::io;
use std::path::PathBuf;

/// Where in a file something was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// A byte offset from the start of the file.
    Byte(u64),
    /// A 1-based line number (text formats).
    Line(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Byte(b) => write!(f, "byte {b}"),
            Location::Line(l) => write!(f, "line {l}"),
        }
    }
}

/// Everything that can go wrong reading or writing a recording.
///
/// Readers never panic on bad input and never return a silently wrong image: they return one of
/// these, after delivering whatever was decoded correctly before the fault.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    /// The file could not be opened (missing, no permission, ...).
    #[error("{path}: cannot open: {source}")]
    Open {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: io::Error,
    },
    /// Reading or writing failed part-way.
    #[error("{path}: I/O error at byte {offset}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Bytes read or written before the failure.
        offset: u64,
        /// The operating system's reason.
        source: io::Error,
    },
    /// The file holds no byte (or, for text, no event line).
    #[error("{path}: the file is empty")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A spike file ends in a partial plane. Raised after every whole plane has been delivered.
    #[error(
        "{path}: {size} bytes is not a whole number of {plane_bytes}-byte planes ({geometry}): \
         {whole_planes} whole planes were read, then {tail_bytes} bytes remain at byte {tail_offset}; \
         the file is truncated or the resolution is wrong"
    )]
    PartialPlane {
        /// The file.
        path: PathBuf,
        /// Bytes read in all.
        size: u64,
        /// Bytes one stored plane takes.
        plane_bytes: u64,
        /// The geometry assumed, e.g. `400x250`.
        geometry: String,
        /// Whole planes delivered before this error.
        whole_planes: u64,
        /// Offset of the partial plane.
        tail_offset: u64,
        /// Bytes in the partial plane.
        tail_bytes: u64,
    },
    /// A spike file's size is not a multiple of the plane size the resolution implies.
    #[error(
        "{path}: {size} bytes do not divide into {plane_bytes}-byte planes of {geometry} \
         ({whole_planes} whole planes and {remainder} bytes over); check the resolution"
    )]
    ResolutionMismatch {
        /// The file.
        path: PathBuf,
        /// File size in bytes.
        size: u64,
        /// Bytes one stored plane takes.
        plane_bytes: u64,
        /// The geometry assumed, e.g. `400x250`.
        geometry: String,
        /// Whole planes the file would hold.
        whole_planes: u64,
        /// Bytes left over.
        remainder: u64,
    },
    /// A malformed line of a text file.
    #[error("{path}: line {line}: {what}")]
    Text {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong, quoting the value.
        what: String,
    },
    /// A binary word or record that breaks the format.
    #[error("{path}: byte {offset}: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Offset of the word or record.
        offset: u64,
        /// What is wrong, quoting the value.
        what: String,
    },
    /// A word whose type the format does not define.
    #[error(
        "{path}: byte {offset}: unknown {format} word type {word_type:#x} (word {value:#x}); \
         ReadOptions::unknown_words = UnknownWords::Skip skips and counts such words"
    )]
    UnknownWord {
        /// The file.
        path: PathBuf,
        /// Offset of the word.
        offset: u64,
        /// `EVT 2.0` or `EVT 3.0`.
        format: &'static str,
        /// The 4-bit type field.
        word_type: u8,
        /// The whole word.
        value: u32,
    },
    /// The file ends inside a word, record or header.
    #[error("{path}: truncated at byte {offset}: {what}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Offset of the incomplete item.
        offset: u64,
        /// What is incomplete.
        what: String,
    },
    /// An event outside the sensor.
    #[error("{path}: {at}: event at ({x}, {y}) is outside the {width}x{height} sensor")]
    OutOfBounds {
        /// The file.
        path: PathBuf,
        /// Where the event is.
        at: Location,
        /// Column found.
        x: u32,
        /// Row found.
        y: u32,
        /// Sensor width.
        width: u32,
        /// Sensor height.
        height: u32,
    },
    /// An event earlier than the one before it.
    #[error(
        "{path}: {at}: timestamp {t_ns} ns is earlier than the previous event's {previous_t_ns} ns; \
         ReadOptions::disorder = Disorder::Clamp repairs (and counts) such events"
    )]
    Unsorted {
        /// The file.
        path: PathBuf,
        /// Where the event is.
        at: Location,
        /// Its timestamp.
        t_ns: i64,
        /// The previous event's timestamp.
        previous_t_ns: i64,
    },
    /// A polarity the format does not allow.
    #[error("{path}: {at}: polarity {value} is not 0 or 1")]
    Polarity {
        /// The file.
        path: PathBuf,
        /// Where the event is.
        at: Location,
        /// The value found.
        value: i64,
    },
    /// A header line that cannot be understood, or that contradicts the options.
    #[error("{path}: header: {what}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong, quoting the line.
        what: String,
    },
    /// Neither the file nor the options give the sensor size.
    #[error("{path}: the sensor size is unknown: {what}; pass ReadOptions::resolution")]
    MissingResolution {
        /// The file.
        path: PathBuf,
        /// Where the size was looked for.
        what: String,
    },
    /// The content fits more than one format, or none.
    #[error("{path}: cannot tell the format: {what}")]
    Ambiguous {
        /// The file.
        path: PathBuf,
        /// What was seen.
        what: String,
    },
    /// A valid file of a kind this crate does not decode.
    #[error("{path}: unsupported: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is not supported.
        what: String,
    },
    /// Data a writer cannot represent in its format.
    #[error("{path}: cannot write event {index}: {what}")]
    Unwritable {
        /// The file (or sink name) being written.
        path: PathBuf,
        /// Index of the event or plane among those written.
        index: u64,
        /// What does not fit, quoting the value.
        what: String,
    },
}

/// The crate's result type.
pub type Result<T, E = FormatError> = std::result::Result<T, E>;
