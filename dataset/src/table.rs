//! Comma-separated tables with a header row, read by column name: a set's `samples.csv`, a
//! `--clips` folder's `clips.csv`. No quoting (neuspike and its scripts write none); empty lines
//! are skipped. Every error names the file, the line and the field.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use eyre::{WrapErr, eyre};

/// A table read whole.
pub struct Table {
    path: PathBuf,
    text: String,
}

/// One row: its line number (1-based, the header being line 1) and its cells.
pub struct Row<'a> {
    path: &'a Path,
    line: usize,
    cells: Vec<&'a str>,
}

impl Table {
    /// Reads `path`; `hint` follows the error when it cannot be read.
    pub fn read(path: &Path, hint: &str) -> eyre::Result<Table> {
        let text = std::fs::read_to_string(path)
            .wrap_err_with(|| format!("{}: cannot read{hint}", path.display()))?;
        Ok(Table {
            path: path.to_owned(),
            text,
        })
    }

    /// The index of column `name` in the header.
    pub fn column(&self, name: &str) -> eyre::Result<usize> {
        self.text
            .lines()
            .next()
            .unwrap_or_default()
            .split(',')
            .position(|h| h.trim() == name)
            .ok_or_else(|| eyre!("{}: no column `{name}` in the header", self.path.display()))
    }

    /// The rows after the header, empty lines left out.
    pub fn rows(&self) -> impl Iterator<Item = Row<'_>> {
        self.text
            .lines()
            .enumerate()
            .skip(1)
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, l)| Row {
                path: &self.path,
                line: i + 1,
                cells: l.split(',').map(str::trim).collect(),
            })
    }
}

impl Row<'_> {
    /// The cell of column `col`, called `name` in errors.
    pub fn field(&self, col: usize, name: &str) -> eyre::Result<&str> {
        self.cells.get(col).copied().ok_or_else(|| {
            eyre!(
                "{} line {}: no field `{name}`",
                self.path.display(),
                self.line
            )
        })
    }

    /// The cell parsed as a `T`; `what` says what it must be.
    pub fn parse<T: FromStr>(&self, col: usize, name: &str, what: &str) -> eyre::Result<T> {
        let v = self.field(col, name)?;
        v.parse().map_err(|_| self.bad(name, v, what))
    }

    /// The cell as a finite number.
    pub fn number(&self, col: usize, name: &str) -> eyre::Result<f64> {
        let v = self.field(col, name)?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| self.bad(name, v, "a finite number"))
    }

    /// The error of a cell `v` of `name` that is not `what`.
    pub fn bad(&self, name: &str, v: &str, what: &str) -> eyre::Report {
        eyre!(
            "{} line {}: `{name}` is {v:?}, not {what}",
            self.path.display(),
            self.line
        )
    }
}
