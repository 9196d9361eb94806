//! Opening any event file: the one place that maps a [`Format`] to its reader.

use std::io::BufReader;
use std::path::Path;

use crate::aedat4::Aedat4Reader;
use crate::dat::DatReader;
use crate::error::{FormatError, Result};
use crate::events::{EventReader, ReadOptions, Resolution};
use crate::raw::RawReader;
use crate::sniff::{Format, sniff};
use crate::text::TextReader;

/// Opens any event file: sniffs its format ([`sniff()`]) and returns the matching reader.
/// Spike files, and HDF5 in a build without the `hdf5` feature, are
/// [`FormatError::Unsupported`].
pub fn open_events(
    path: impl AsRef<Path>,
    opts: &ReadOptions,
) -> Result<Box<dyn EventReader + Send>> {
    let path = path.as_ref();
    Ok(open_event_format(path, sniff(path)?, opts)?.0)
}

/// Opens an event file of a known format. With `allow_unknown_size`, a file that states no size
/// (and no [`ReadOptions::resolution`]) is read without bounds, for summaries.
pub fn open_event_format(
    path: &Path,
    format: Format,
    opts: &ReadOptions,
) -> Result<(Box<dyn EventReader + Send>, Option<Resolution>)> {
    let open = crate::open_file;
    let p = path.to_path_buf();
    Ok(match format {
        Format::EventText => {
            let file = BufReader::with_capacity(256 * 1024, open(path)?);
            let r = TextReader::from_reader(file, p, opts)?;
            let known = r.known_resolution();
            (Box::new(r), known)
        }
        Format::PropheseeRaw(_) => {
            let r = RawReader::from_reader(open(path)?, p, opts)?;
            let known = r.known_resolution();
            (Box::new(r), known)
        }
        Format::PropheseeDat => {
            let r = DatReader::from_reader(open(path)?, p, opts)?;
            let known = r.known_resolution();
            (Box::new(r), known)
        }
        Format::PkuSpikes => {
            return Err(FormatError::Unsupported {
                path: p,
                what: "spike planes, not events (read them with pku::PkuReader)".into(),
            });
        }
        Format::Aedat4 => {
            // Opened by path, so that sizes it claims are also checked against its length.
            let r = Aedat4Reader::open(path, opts)?;
            let known = r.known_resolution();
            (Box::new(r), known)
        }
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => {
            let r = crate::hdf5::Hdf5Reader::open(path, opts)?;
            let known = r.known_resolution();
            (Box::new(r), known)
        }
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => {
            return Err(FormatError::Unsupported {
                path: p,
                what: "HDF5: this build has no HDF5 support (it needs libhdf5: `apt install \
                       libhdf5-dev`, then build with `--features hdf5`)"
                    .into(),
            });
        }
    })
}
