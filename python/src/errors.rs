//! The package's exceptions: `neuspike.Error` and a class per kind, each with the Rust side's
//! one-line message.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    neuspike,
    Error,
    PyException,
    "Every error neuspike raises: the one-line message the Rust side gives."
);
create_exception!(
    neuspike,
    FormatError,
    Error,
    "A file that cannot be opened, read or written: names the file, the byte offset or line, and the value."
);
create_exception!(
    neuspike,
    ConfigError,
    Error,
    "A setting refused: a camera or scene argument, a thread count; names the setting and the value."
);
create_exception!(
    neuspike,
    InputError,
    Error,
    "Arrays a kernel refuses: a shape, an index, an unsorted event; names the argument and the value."
);

/// A format error as `neuspike.FormatError`.
pub fn format(e: neuspike_formats::FormatError) -> PyErr {
    FormatError::new_err(e.to_string())
}

/// A file's fault given as text, as `neuspike.FormatError`.
pub fn format_text(e: impl std::fmt::Display) -> PyErr {
    FormatError::new_err(e.to_string())
}

/// A kernel's refusal as `neuspike.InputError`.
pub fn input(e: impl std::fmt::Display) -> PyErr {
    InputError::new_err(e.to_string())
}

/// A refused setting as `neuspike.ConfigError`.
pub fn config(e: impl std::fmt::Display) -> PyErr {
    ConfigError::new_err(e.to_string())
}
