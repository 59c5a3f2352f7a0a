//! Where loaders get the bytes of referenced files from.
//!
//! Loaders never touch the file system directly: a TOML scene names meshes
//! by relative path and an OBJ names its MTL libraries, and both are read
//! through a [`FileSource`]. On disk ([`DiskFiles`]) a read refuses anything
//! that is not a regular file (a scene naming `/dev/zero` must not hang) and
//! anything larger than the configured byte limit; in memory
//! ([`MemoryFiles`]) the fuzz targets and tests get the same loaders without
//! any I/O.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use super::error::{Origin, SceneError};

/// Source of the text of files referenced by a scene.
pub trait FileSource {
    /// The whole file at `path` as UTF-8 text. Errors name the path.
    fn read_text(&self, path: &Path, max_bytes: u64) -> Result<String, SceneError>;

    /// Whether anything is at `path`. Only a path that is certainly absent
    /// is `false` (a scene's optional mesh then falls back to its
    /// stand-in); anything else, unreadable included, is left for
    /// [`FileSource::read_text`] to report.
    fn exists(&self, path: &Path) -> bool;
}

/// Reads from the file system.
#[derive(Clone, Copy, Debug, Default)]
pub struct DiskFiles;

impl FileSource for DiskFiles {
    fn read_text(&self, path: &Path, max_bytes: u64) -> Result<String, SceneError> {
        read_file_text(path, max_bytes)
    }

    fn exists(&self, path: &Path) -> bool {
        !matches!(std::fs::metadata(path), Err(e) if e.kind() == std::io::ErrorKind::NotFound)
    }
}

/// An in-memory file system: path → contents. Paths are compared as given
/// (after the loader joins them with the scene's directory).
#[derive(Clone, Debug, Default)]
pub struct MemoryFiles {
    /// The files.
    pub files: HashMap<PathBuf, String>,
}

impl MemoryFiles {
    /// An empty set of files.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add (or replace) a file.
    pub fn insert(&mut self, path: impl Into<PathBuf>, text: impl Into<String>) -> &mut Self {
        self.files.insert(path.into(), text.into());
        self
    }
}

impl FileSource for MemoryFiles {
    fn read_text(&self, path: &Path, max_bytes: u64) -> Result<String, SceneError> {
        match self.files.get(path) {
            Some(text) if text.len() as u64 > max_bytes => Err(SceneError::TooLarge {
                origin: Origin::file(path),
                what: "file byte",
                count: text.len() as u64,
                limit: max_bytes,
            }),
            Some(text) => Ok(text.clone()),
            None => Err(SceneError::Io {
                path: path.to_owned(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            }),
        }
    }

    fn exists(&self, path: &Path) -> bool {
        self.files.contains_key(path)
    }
}

/// Read a regular file of at most `max_bytes` bytes as UTF-8 text.
pub fn read_file_text(path: &Path, max_bytes: u64) -> Result<String, SceneError> {
    let io_err = |source: std::io::Error| SceneError::Io {
        path: path.to_owned(),
        source,
    };
    let (file, len) = open_regular(path, max_bytes)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    // `take` guards against files that grow while we read them.
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io_err)?;
    if bytes.len() as u64 > max_bytes {
        return Err(SceneError::TooLarge {
            origin: Origin::file(path),
            what: "file byte",
            count: bytes.len() as u64,
            limit: max_bytes,
        });
    }
    text_from_bytes(bytes, path)
}

/// The file at `path` opened for reading, and its length, where it is a regular file of at
/// most `max_bytes` bytes.
pub(crate) fn open_regular(
    path: &Path,
    max_bytes: u64,
) -> Result<(std::fs::File, u64), SceneError> {
    let io_err = |source: std::io::Error| SceneError::Io {
        path: path.to_owned(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(io_err)?;
    if !meta.is_file() {
        let what = if meta.is_dir() {
            "is a directory"
        } else {
            "is not a regular file"
        };
        return Err(io_err(std::io::Error::other(what)));
    }
    if meta.len() > max_bytes {
        return Err(SceneError::TooLarge {
            origin: Origin::file(path),
            what: "file byte",
            count: meta.len(),
            limit: max_bytes,
        });
    }
    Ok((std::fs::File::open(path).map_err(io_err)?, meta.len()))
}

/// UTF-8 decode, reporting the line of the first invalid byte.
pub fn text_from_bytes(bytes: Vec<u8>, path: &Path) -> Result<String, SceneError> {
    String::from_utf8(bytes).map_err(|e| {
        let good = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let line = 1 + bytes[..good].iter().filter(|&&b| b == b'\n').count();
        let start = bytes[..good]
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |p| p + 1);
        invalid_utf8(path, line, &bytes[start..], good - start)
    })
}

/// The error of invalid UTF-8 in line `line` (1-based) of `path`, whose bytes `line_bytes`
/// are valid up to `good`.
pub(crate) fn invalid_utf8(path: &Path, line: usize, line_bytes: &[u8], good: usize) -> SceneError {
    SceneError::Syntax {
        origin: Origin {
            file: Some(path.to_owned()),
            line: Some(u32::try_from(line).unwrap_or(u32::MAX)),
            column: Some(u32::try_from(good + 1).unwrap_or(u32::MAX)),
            key: None,
        },
        message: format!("invalid UTF-8 (byte 0x{:02x})", line_bytes[good]),
    }
}
