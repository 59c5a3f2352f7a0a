//! The renderer's shader compiled as a renderer compiles it: `glslc` (or the program
//! `VKRT_GLSLC` names), `--target-env=vulkan1.2 -fshader-stage=compute`, with vkrt's include
//! directory; once as it runs through vkrt, once with `VKRT_NATIVE_RAY_QUERY=1`, under which
//! the include is empty and the shader queries the driver's own structure.

use std::path::{Path, PathBuf};

/// The include line a shader gives itself (inserted where it is missing).
pub const INCLUDE: &str = "vkrt/ext_ray_query.glsl";

/// The define under which the include leaves the driver's ray query to the shader.
pub const NATIVE_DEFINE: &str = "VKRT_NATIVE_RAY_QUERY";

/// `source` with `#include "vkrt/ext_ray_query.glsl"` after its last `#extension` line
/// (after `#version` where it has none), and a `#line` so that messages keep the file's line
/// numbers; unchanged (and `false`) where it includes the file already.
pub fn with_include(source: &str) -> (String, bool) {
    let includes = source.lines().any(|l| {
        let t = l.trim_start();
        t.starts_with("#include") && t.contains(INCLUDE)
    });
    if includes {
        return (source.to_owned(), false);
    }
    let directive = |l: &str, name: &str| {
        let t = l.trim_start();
        t.strip_prefix('#')
            .is_some_and(|rest| rest.trim_start().starts_with(name))
    };
    let lines: Vec<&str> = source.split_inclusive('\n').collect();
    let after = lines
        .iter()
        .rposition(|l| directive(l, "extension"))
        .or_else(|| lines.iter().position(|l| directive(l, "version")));
    let at = after.map_or(0, |k| k + 1);
    let mut out = String::with_capacity(source.len() + 64);
    for l in &lines[..at] {
        out.push_str(l);
    }
    if !out.is_empty() && !out.ends_with('\n') {
        out.push('\n');
    }
    out.push_str(&format!("#include \"{INCLUDE}\"\n#line {}\n", at + 1));
    for l in &lines[at..] {
        out.push_str(l);
    }
    (out, true)
}

/// Why a shader did not compile.
#[derive(Debug, thiserror::Error)]
pub enum CompileError {
    /// The compiler could not be run.
    #[error("cannot run the shader compiler `{program}` ({reason}); install glslc (./x setup) or name one in VKRT_GLSLC (for Slang and HLSL: slangc, or VKRT_SLANGC)")]
    NoCompiler {
        /// The program.
        program: String,
        /// Why.
        reason: String,
    },
    /// The compiler refused the shader.
    #[error("{shader} does not compile{variant}:\n{message}")]
    Refused {
        /// The shader's path.
        shader: String,
        /// Which variant (" with VKRT_NATIVE_RAY_QUERY=1" for the driver's).
        variant: &'static str,
        /// The compiler's messages.
        message: String,
    },
    /// A temporary file could not be written or read.
    #[error("the shader compiler's files: {0}")]
    Io(#[from] std::io::Error),
}

/// Slang's compiler: `VKRT_SLANGC`, else `slangc`.
pub fn slang_compiler() -> String {
    std::env::var("VKRT_SLANGC")
        .ok()
        .filter(|s| !s.trim().is_empty())
        .unwrap_or_else(|| "slangc".into())
}

/// A Slang or HLSL compute shader (entry point `main`) compiled to SPIR-V by Slang's
/// compiler: the words, for the driver's ray query (the SPIR-V pass lowers them for vkrt).
pub fn compile_slang(shader: &Path) -> Result<Vec<u32>, CompileError> {
    let dir = TempDir::new("shader-check-slang")?;
    let out = dir.path().join("shader.spv");
    let program = slang_compiler();
    let result = std::process::Command::new(&program)
        .arg(shader)
        .args([
            "-target", "spirv", "-entry", "main", "-stage", "compute", "-o",
        ])
        .arg(&out)
        .output()
        .map_err(|e| CompileError::NoCompiler {
            program: program.clone(),
            reason: e.to_string(),
        })?;
    if !result.status.success() {
        return Err(CompileError::Refused {
            shader: shader.display().to_string(),
            variant: " with Slang's compiler",
            message: (String::from_utf8_lossy(&result.stderr).into_owned()
                + &String::from_utf8_lossy(&result.stdout))
                .trim_end()
                .to_owned(),
        });
    }
    read_words(&program, &out)
}

fn read_words(program: &str, out: &Path) -> Result<Vec<u32>, CompileError> {
    let bytes = std::fs::read(out)?;
    if bytes.len() % 4 != 0 {
        return Err(CompileError::Io(std::io::Error::other(format!(
            "{program} wrote {} bytes of SPIR-V, not whole words",
            bytes.len()
        ))));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

/// The compiler's program: `VKRT_GLSLC`, else `glslc`.
pub fn compiler() -> String {
    std::env::var("VKRT_GLSLC")
        .ok()
        .filter(|s| !s.trim().is_empty())
        .unwrap_or_else(|| "glslc".into())
}

/// A directory of this process's own under the temporary directory, removed when dropped.
pub struct TempDir(PathBuf);

impl TempDir {
    /// A fresh directory named after `what`.
    pub fn new(what: &str) -> std::io::Result<Self> {
        use std::sync::atomic::{AtomicU32, Ordering};
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("vkrt-{what}-{}-{n}", std::process::id()));
        if dir.exists() {
            std::fs::remove_dir_all(&dir)?;
        }
        std::fs::create_dir_all(&dir)?;
        Ok(Self(dir))
    }

    /// Its path.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `source` (read from `shader`) compiled with the include directory `include` (then the
/// shader's own directory), with the native define where `native`: the SPIR-V words.
pub fn compile(
    shader: &Path,
    source: &str,
    include: &Path,
    native: bool,
) -> Result<Vec<u32>, CompileError> {
    let dir = TempDir::new("shader-check")?;
    let name = shader
        .file_name()
        .map_or_else(|| "shader.comp".into(), |n| n.to_os_string());
    let src = dir.path().join(&name);
    let out = dir.path().join("shader.spv");
    std::fs::write(&src, source)?;
    let program = compiler();
    let mut cmd = std::process::Command::new(&program);
    // The copy is compiled elsewhere: the shader's own directory is searched after vkrt's,
    // so its other includes are found where they would be.
    let own_dir = match shader.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    cmd.arg("--target-env=vulkan1.2")
        .arg("-fshader-stage=compute")
        .arg("-I")
        .arg(include)
        .arg("-I")
        .arg(&own_dir);
    if native {
        cmd.arg(format!("-D{NATIVE_DEFINE}=1"));
    }
    cmd.arg("-o").arg(&out).arg(&src);
    let result = cmd.output().map_err(|e| CompileError::NoCompiler {
        program: program.clone(),
        reason: e.to_string(),
    })?;
    if !result.status.success() {
        // The messages name the copy; name the shader as it was given.
        let text = String::from_utf8_lossy(&result.stderr).into_owned()
            + &String::from_utf8_lossy(&result.stdout);
        let message = text
            .replace(&src.display().to_string(), &shader.display().to_string())
            .trim_end()
            .to_owned();
        return Err(CompileError::Refused {
            shader: shader.display().to_string(),
            variant: if native {
                " with VKRT_NATIVE_RAY_QUERY=1 (the driver's ray query)"
            } else {
                " through vkrt's include"
            },
            message,
        });
    }
    read_words(&program, &out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_include_goes_after_the_last_extension() {
        let src = "#version 460\n#extension A : require\n#extension B : require\nvoid main() {}\n";
        let (out, added) = with_include(src);
        assert!(added);
        assert_eq!(
            out,
            "#version 460\n#extension A : require\n#extension B : require\n\
             #include \"vkrt/ext_ray_query.glsl\"\n#line 4\nvoid main() {}\n"
        );
        let (again, added) = with_include(&out);
        assert!(!added);
        assert_eq!(again, out);
    }

    #[test]
    fn without_extensions_it_follows_the_version() {
        let (out, _) = with_include("#version 460\nvoid main() {}");
        assert_eq!(
            out,
            "#version 460\n#include \"vkrt/ext_ray_query.glsl\"\n#line 2\nvoid main() {}"
        );
        let (out, _) = with_include("void main() {}");
        assert!(out.starts_with("#include"));
    }
}
