//! The one error type of the scene layer.
//!
//! Every variant carries an [`Origin`] — file, line, column and key path, as
//! far as they are known — so that a message always says *where* the problem
//! is. Loaders fill in what they know: the TOML loader maps a key path such as
//! `spheres[2].radius` to its line in the file, the OBJ loader reports the
//! line of the offending statement, and model-level validation (which knows
//! only key paths) leaves file and line to the loader that called it.

use std::fmt;
use std::path::PathBuf;

/// Where something is: any of file, line, column, key path (all optional).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Origin {
    /// The file the problem is in.
    pub file: Option<PathBuf>,
    /// 1-based line number in `file`.
    pub line: Option<u32>,
    /// 1-based column (in characters) on `line`.
    pub column: Option<u32>,
    /// Key path inside the scene, e.g. `spheres[2].radius` or
    /// `materials.glass.ior`.
    pub key: Option<String>,
}

impl Origin {
    /// An origin that names only a file.
    pub fn file(path: impl Into<PathBuf>) -> Self {
        Self {
            file: Some(path.into()),
            ..Self::default()
        }
    }

    /// An origin that names a file and a 1-based line.
    pub fn line(path: impl Into<PathBuf>, line: usize) -> Self {
        Self {
            file: Some(path.into()),
            line: Some(u32::try_from(line).unwrap_or(u32::MAX)),
            ..Self::default()
        }
    }

    /// An origin that names only a key path.
    pub fn key(key: impl Into<String>) -> Self {
        Self {
            key: Some(key.into()),
            ..Self::default()
        }
    }
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut wrote = false;
        if let Some(file) = &self.file {
            write!(f, "{}", file.display())?;
            if let Some(line) = self.line {
                write!(f, ":{line}")?;
                if let Some(col) = self.column {
                    write!(f, ":{col}")?;
                }
            }
            wrote = true;
        }
        if let Some(key) = &self.key {
            if wrote {
                f.write_str(": ")?;
            }
            // Pathological nesting can make key paths huge; keep both ends.
            const MAX_CHARS: usize = 160;
            if key.chars().count() > MAX_CHARS {
                let head: String = key.chars().take(MAX_CHARS / 2).collect();
                let tail: Vec<char> = key.chars().rev().take(MAX_CHARS / 2).collect();
                let tail: String = tail.into_iter().rev().collect();
                write!(f, "`{head}…{tail}`")?;
            } else {
                write!(f, "`{key}`")?;
            }
            wrote = true;
        }
        if !wrote {
            f.write_str("scene")?;
        }
        Ok(())
    }
}

/// Everything that can go wrong while loading, generating or validating a
/// scene. Display messages name the file, line, key or object at fault.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A file could not be read (missing, not a regular file, unreadable).
    #[error("{}: cannot read file: {source}", path.display())]
    Io {
        /// The path as it was given (joined with the scene's directory).
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },

    /// `Scene::load` was given a file whose extension names no format.
    #[error(
        "{}: unsupported scene file extension {extension:?}: expected .toml, .obj, or .scn/.txt (Bidmon's plain-text format)",
        path.display()
    )]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
        /// Its extension ("" when it has none).
        extension: String,
    },

    /// Malformed text: TOML, OBJ, MTL or .scn syntax, a value of the
    /// wrong type, an unknown key, a missing key, invalid UTF-8.
    #[error("{origin}: {message}")]
    Syntax {
        /// Where.
        origin: Origin,
        /// What is wrong, e.g. ``unknown field `colour`, expected one of ...``.
        message: String,
    },

    /// A NaN or infinite number where a finite one is required.
    #[error("{origin}: {value} is not a finite number")]
    NonFinite {
        /// Where.
        origin: Origin,
        /// The offending value as text (`NaN`, `inf`, `[1, NaN, 0]`).
        value: String,
    },

    /// An index (vertex, normal, material, ...) past the end of its list.
    #[error("{origin}: index {index} is out of range: {what} has {len} entries")]
    IndexOutOfRange {
        /// Where.
        origin: Origin,
        /// The index as written (may be negative or zero in OBJ files).
        index: i64,
        /// What the index refers into, e.g. "vertex list".
        what: String,
        /// Number of entries available.
        len: u64,
    },

    /// A number outside its documented range (negative radius, zero-size
    /// image, samples per pixel above [`MAX_SPP`](super::MAX_SPP), ...).
    #[error("{origin}: {value} is out of range: {expected}")]
    OutOfRange {
        /// Where.
        origin: Origin,
        /// The offending value as text.
        value: String,
        /// The allowed range in words, e.g. "must be > 0".
        expected: String,
    },

    /// A name (material, generator kind) that is not defined.
    #[error("{origin}: unknown {kind} `{name}`{hint}")]
    UnknownName {
        /// Where.
        origin: Origin,
        /// What kind of name, e.g. "material".
        kind: &'static str,
        /// The name as written.
        name: String,
        /// Extra help, e.g. "; defined materials: red, white" (may be empty).
        hint: Box<str>,
    },

    /// A geometric or logical inconsistency: camera `up` parallel to the view
    /// direction, quad light with parallel edges, missing required key.
    #[error("{origin}: {message}")]
    Invalid {
        /// Where.
        origin: Origin,
        /// What is wrong.
        message: String,
    },

    /// More of something than the stated limit (triangles, spheres, file
    /// bytes, ...).
    #[error("{origin}: {what} count {count} exceeds the limit of {limit}")]
    TooLarge {
        /// Where.
        origin: Origin,
        /// What was counted, e.g. "triangle".
        what: &'static str,
        /// How many there are (or would be).
        count: u64,
        /// The limit.
        limit: u64,
    },

    /// Nothing to render: no triangles (after dropping degenerate ones) and no
    /// spheres.
    #[error("{origin}: scene is empty: it has no triangles and no spheres{detail}")]
    Empty {
        /// Where (usually the file).
        origin: Origin,
        /// Extra detail, e.g. " (all 12 triangles had zero area)".
        detail: String,
    },
}

impl SceneError {
    /// The origin of this error, if the variant has one.
    pub fn origin(&self) -> Option<&Origin> {
        match self {
            SceneError::Io { .. } | SceneError::UnsupportedFormat { .. } => None,
            SceneError::Syntax { origin, .. }
            | SceneError::NonFinite { origin, .. }
            | SceneError::IndexOutOfRange { origin, .. }
            | SceneError::OutOfRange { origin, .. }
            | SceneError::UnknownName { origin, .. }
            | SceneError::Invalid { origin, .. }
            | SceneError::TooLarge { origin, .. }
            | SceneError::Empty { origin, .. } => Some(origin),
        }
    }

    /// Mutable access to the origin, for loaders that add file and line.
    pub fn origin_mut(&mut self) -> Option<&mut Origin> {
        match self {
            SceneError::Io { .. } | SceneError::UnsupportedFormat { .. } => None,
            SceneError::Syntax { origin, .. }
            | SceneError::NonFinite { origin, .. }
            | SceneError::IndexOutOfRange { origin, .. }
            | SceneError::OutOfRange { origin, .. }
            | SceneError::UnknownName { origin, .. }
            | SceneError::Invalid { origin, .. }
            | SceneError::TooLarge { origin, .. }
            | SceneError::Empty { origin, .. } => Some(origin),
        }
    }

    #[cfg(feature = "scene-files")]
    pub(crate) fn syntax(origin: Origin, message: impl Into<String>) -> Self {
        SceneError::Syntax {
            origin,
            message: message.into(),
        }
    }

    pub(crate) fn invalid(origin: Origin, message: impl Into<String>) -> Self {
        SceneError::Invalid {
            origin,
            message: message.into(),
        }
    }

    pub(crate) fn out_of_range(
        origin: Origin,
        value: impl fmt::Display,
        expected: impl Into<String>,
    ) -> Self {
        SceneError::OutOfRange {
            origin,
            value: value.to_string(),
            expected: expected.into(),
        }
    }
}
