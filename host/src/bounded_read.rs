//! Reading an input file with a size limit: a regular file only (not a directory, a device such
//! as `/dev/zero` or a pipe), at most a given number of bytes even if it grows while read.

use std::io::{self, Read};
use std::path::Path;

/// The bytes of the regular file `path`, refused when larger than `limit` bytes.
///
/// # Errors
/// The I/O error; [`io::ErrorKind::InvalidInput`] for a path that is not a regular file or a
/// file above the limit.
pub fn read_bounded(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        let what = if meta.is_dir() {
            "a directory"
        } else {
            "not a regular file"
        };
        return Err(io::Error::new(io::ErrorKind::InvalidInput, what));
    }
    let too_large = |bytes: u64| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{bytes} bytes, more than the limit of {limit}"),
        )
    };
    if meta.len() > limit {
        return Err(too_large(meta.len()));
    }
    let mut bytes = Vec::new();
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}
