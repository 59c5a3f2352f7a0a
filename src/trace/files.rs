//! Ray and hit files of `vkrt trace`.
//!
//! - `.rays`: little-endian binary, 8 f32 per ray: ox, oy, oz, tmin, dx, dy, dz, tmax
//!   (exactly [`Ray`]'s layout).
//! - `.csv` rays: one ray per line, `ox,oy,oz,dx,dy,dz[,tmin,tmax]` (tmin defaults to 0 and
//!   tmax to `inf`, unbounded); blank lines and lines starting with `#` are skipped,
//!   and a first line that is not numbers is taken as a header.
//! - hits, binary (any extension but `.csv`): 16 bytes per ray, t f32, prim u32, u f32,
//!   v f32 (t = +inf and prim = 4294967295 for a miss); `.csv`: a `t,prim,u,v` header, then
//!   one line per ray (`inf,-1,0,0` for a miss).
//!
//! `tmax = inf` (binary or CSV) is an unbounded ray. Other values that parse but are NaN or
//! infinite are kept: such rays are answered as misses and counted
//! ([`super::count_invalid`]).

use std::path::Path;

use super::{Hit, Ray};

/// Why a ray file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum RayFileError {
    /// The file could not be read.
    #[error("{path}: {reason}")]
    Io {
        /// The ray file.
        path: String,
        /// The I/O error's message.
        reason: String,
    },
    /// A binary ray file whose length is not a multiple of 32 bytes.
    #[error(
        "{path}: {len} bytes is not a whole number of 32-byte rays (8 little-endian f32 each)"
    )]
    Truncated {
        /// The ray file.
        path: String,
        /// Its length in bytes.
        len: usize,
    },
    /// A CSV ray file that is not UTF-8, or a line with a field that is not a number or
    /// with neither 6 nor 8 values.
    #[error("{path}:{line}: {reason}")]
    Csv {
        /// The ray file.
        path: String,
        /// The offending line, 1-based (0 when the file is not UTF-8).
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
}

fn is_csv(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// Reads a `.rays` or `.csv` ray file.
pub fn read_rays(path: &Path) -> Result<Vec<Ray>, RayFileError> {
    let bytes = std::fs::read(path).map_err(|e| RayFileError::Io {
        path: path.display().to_string(),
        reason: e.to_string(),
    })?;
    if is_csv(path) {
        let text = String::from_utf8(bytes).map_err(|_| RayFileError::Csv {
            path: path.display().to_string(),
            line: 0,
            reason: "not UTF-8 text".into(),
        })?;
        parse_csv(&text).map_err(|(line, reason)| RayFileError::Csv {
            path: path.display().to_string(),
            line,
            reason,
        })
    } else {
        parse_binary(&bytes).ok_or(RayFileError::Truncated {
            path: path.display().to_string(),
            len: bytes.len(),
        })
    }
}

/// Binary rays, or `None` if the length is not a multiple of 32 bytes.
pub fn parse_binary(bytes: &[u8]) -> Option<Vec<Ray>> {
    if bytes.len() % 32 != 0 {
        return None;
    }
    Some(
        bytes
            .chunks_exact(32)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap());
                Ray {
                    origin: [f(0), f(1), f(2)],
                    tmin: f(3),
                    dir: [f(4), f(5), f(6)],
                    tmax: f(7),
                }
            })
            .collect(),
    )
}

/// CSV rays; errors carry the 1-based line.
pub fn parse_csv(text: &str) -> Result<Vec<Ray>, (usize, String)> {
    let mut rays = Vec::new();
    let mut first = true;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Result<Vec<f32>, _> = fields.iter().map(|f| f.parse::<f32>()).collect();
        let values = match parsed {
            Ok(v) => v,
            Err(_) if first => {
                first = false;
                continue; // header
            }
            Err(_) => {
                let bad = fields.iter().find(|f| f.parse::<f32>().is_err()).unwrap();
                return Err((i + 1, format!("`{bad}` is not a number")));
            }
        };
        first = false;
        if values.len() != 6 && values.len() != 8 {
            return Err((
                i + 1,
                format!(
                    "{} values; want ox,oy,oz,dx,dy,dz[,tmin,tmax]",
                    values.len()
                ),
            ));
        }
        let (tmin, tmax) = if values.len() == 8 {
            (values[6], values[7])
        } else {
            (0.0, f32::INFINITY)
        };
        rays.push(Ray {
            origin: [values[0], values[1], values[2]],
            tmin,
            dir: [values[3], values[4], values[5]],
            tmax,
        });
    }
    Ok(rays)
}

/// Hits as the file at `path` wants them (CSV by extension, else binary).
pub fn encode_hits(path: &Path, hits: &[Hit]) -> Vec<u8> {
    if is_csv(path) {
        let mut s = String::from("t,prim,u,v\n");
        for h in hits {
            if h.is_hit() {
                s.push_str(&format!("{},{},{},{}\n", h.t, h.prim, h.u, h.v));
            } else {
                s.push_str("inf,-1,0,0\n");
            }
        }
        s.into_bytes()
    } else {
        bytemuck::cast_slice(hits).to_vec()
    }
}

/// Rays as a binary `.rays` file.
pub fn encode_rays(rays: &[Ray]) -> Vec<u8> {
    bytemuck::cast_slice(rays).to_vec()
}
