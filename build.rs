//! Generates `$OUT_DIR/shaders.rs`: one `ShaderBlob` constant per kernel variant, with the
//! bindings, specialization constants and workgroup size reflected from the SPIR-V.
//!
//! With the `shaderc` feature (the repository's own builds) every `glsl/**/*.comp` is
//! compiled to SPIR-V (Vulkan 1.2, optimised) here, and the result is compared with the
//! checked-in copy `kernels/shaders.rs`: `VKRT_KERNELS=update` rewrites that copy,
//! `VKRT_KERNELS=check` fails the build where it differs (CI), otherwise a difference is a
//! warning. Without the feature (a library dependent: no C++ toolchain, no 9-minute shaderc
//! build) the checked-in copy is used as it is.
//!
//! Variants: a line `//! variant NAME DEF[=VALUE] ...` in a kernel adds a variant compiled
//! with those macro definitions. A kernel without such lines compiles once. Kernel names
//! mirror the path: `glsl/prims/scan.comp` is `prims.scan`, its variant `inc` is
//! `prims.scan.inc`, and the Rust constant is `PRIMS_SCAN_INC`.
//!
//! Every shader error is collected and reported (file and line, from the compiler)
//! before the build fails.

#![cfg_attr(not(feature = "shaderc"), allow(dead_code))]

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The compiled kernels as checked in, relative to the manifest.
const CHECKED_IN: &str = "kernels/shaders.rs";
/// What the checked-in kernels were compiled from: `sha256sum`'s listing of `glsl/`.
const SOURCES: &str = "kernels/glsl.sha256";

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("shaders.rs");
    println!("cargo:rerun-if-changed=glsl");
    let sources = source_listing(&root);
    #[cfg(feature = "shaderc")]
    {
        println!("cargo:rerun-if-env-changed=VKRT_KERNELS");
        let text = compile_all(&root);
        std::fs::write(&out, &text).expect("cannot write shaders.rs");
        sync_checked_in(&root, &text, &sources);
        export_for_dependents(&root, &text);
    }
    #[cfg(not(feature = "shaderc"))]
    {
        println!("cargo:rerun-if-changed={CHECKED_IN}");
        println!("cargo:rerun-if-changed={SOURCES}");
        check_sources(&root, &sources);
        let checked_in = root.join(CHECKED_IN);
        let text = std::fs::read_to_string(&checked_in).unwrap_or_else(|e| {
            panic!(
                "{}: {e}: the compiled kernels are missing; build with the `shaderc` feature \
                 to compile glsl/ (needs cmake, ninja, python3 and a C++ compiler)",
                checked_in.display()
            )
        });
        std::fs::write(&out, &text).expect("cannot write shaders.rs");
        export_for_dependents(&root, &text);
    }
}

/// What a dependent's build script finds through `links = "vkrt"`: `DEP_VKRT_INCLUDE`, the
/// GLSL library's include directory (`#include "vkrt/ext_ray_query.glsl"`), and
/// `DEP_VKRT_RAY_QUERY_LIBRARY`, the SPIR-V library the pass `vkrt::spirv` links into
/// shaders, as a `.spv` file (taken from the kernel table `text`).
fn export_for_dependents(root: &Path, text: &str) {
    println!(
        "cargo:include={}",
        root.join("glsl").join("include").display()
    );
    let Some(words) = kernel_words(text, "SPIRV_RAY_QUERY_LIBRARY") else {
        return;
    };
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let path = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("ray_query_library.spv");
    std::fs::write(&path, bytes).expect("cannot write ray_query_library.spv");
    println!("cargo:ray_query_library={}", path.display());
}

/// The SPIR-V words of kernel `ident` in a generated kernel table.
fn kernel_words(text: &str, ident: &str) -> Option<Vec<u32>> {
    let start = text.find(&format!("pub static {ident}: ShaderBlob"))?;
    let rest = &text[start..];
    let list = &rest[rest.find("spirv: &[")? + "spirv: &[".len()..];
    let list = &list[..list.find(']')?];
    list.split(',')
        .map(str::trim)
        .filter(|w| !w.is_empty())
        .map(|w| u32::from_str_radix(w.trim_start_matches("0x"), 16).ok())
        .collect()
}

/// Without shaderc the checked-in kernels are used as they are, so they must have been
/// compiled from the GLSL beside them: a kernel edited since is a build error naming it, never
/// a stale kernel run silently. (A package without `glsl/` has nothing to be stale against.)
#[cfg(not(feature = "shaderc"))]
fn check_sources(root: &Path, sources: &str) {
    if !root.join("glsl").is_dir() {
        return;
    }
    let recorded = std::fs::read_to_string(root.join(SOURCES)).unwrap_or_default();
    let changed = changed_sources(&recorded, sources);
    if !changed.is_empty() {
        eprintln!(
            "error: {CHECKED_IN} was not compiled from this glsl/ ({} changed since: {}): build \
             with `--features shaderc` to compile the kernels (`./x` does so by itself)",
            changed.len(),
            changed.join(", ")
        );
        std::process::exit(1);
    }
}

/// The files whose line differs between two listings (added, removed or edited).
#[cfg(not(feature = "shaderc"))]
fn changed_sources(a: &str, b: &str) -> Vec<String> {
    let set =
        |s: &str| -> std::collections::BTreeSet<String> { s.lines().map(str::to_owned).collect() };
    let (a, b) = (set(a), set(b));
    let mut files: Vec<String> = a
        .symmetric_difference(&b)
        .filter_map(|line| line.split_once("  ").map(|(_, path)| path.to_owned()))
        .collect();
    files.sort();
    files.dedup();
    files
}

/// `sha256sum`'s listing of every file under `root/glsl`, sorted by path: what
/// `kernels/glsl.sha256` records for the checked-in kernels, and what `./x` compares with
/// `sha256sum` to decide whether a build needs shaderc.
fn source_listing(root: &Path) -> String {
    let mut files = Vec::new();
    collect_files(&root.join("glsl"), &mut files);
    let mut rows: Vec<(String, PathBuf)> = files
        .into_iter()
        .map(|f| {
            let rel = f
                .strip_prefix(root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            (rel, f)
        })
        .collect();
    // Byte order of the paths, as `LC_ALL=C sort` gives.
    rows.sort();
    let mut listing = String::new();
    for (rel, path) in rows {
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{rel}: cannot read: {e}"));
        let _ = writeln!(listing, "{}  {rel}", hex(&sha256(&bytes)));
    }
    listing
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 (FIPS 180-4), so that build.rs needs no dependency to hash the kernels' sources.
fn sha256(data: &[u8]) -> [u8; 32] {
    const K: [u32; 64] = [
        0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4,
        0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe,
        0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f,
        0x4a7484aa, 0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7,
        0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85, 0x2e1b2138, 0x4d2c6dfc,
        0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b,
        0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116,
        0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
        0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7,
        0xc67178f2,
    ];
    let mut h: [u32; 8] = [
        0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab,
        0x5be0cd19,
    ];
    let mut message = data.to_vec();
    message.push(0x80);
    while message.len() % 64 != 56 {
        message.push(0);
    }
    message.extend_from_slice(&((data.len() as u64) * 8).to_be_bytes());
    for block in message.chunks_exact(64) {
        let mut w = [0u32; 64];
        for (i, word) in block.chunks_exact(4).enumerate() {
            w[i] = u32::from_be_bytes([word[0], word[1], word[2], word[3]]);
        }
        for i in 16..64 {
            let s0 = w[i - 15].rotate_right(7) ^ w[i - 15].rotate_right(18) ^ (w[i - 15] >> 3);
            let s1 = w[i - 2].rotate_right(17) ^ w[i - 2].rotate_right(19) ^ (w[i - 2] >> 10);
            w[i] = w[i - 16]
                .wrapping_add(s0)
                .wrapping_add(w[i - 7])
                .wrapping_add(s1);
        }
        let [mut a, mut b, mut c, mut d, mut e, mut f, mut g, mut hh] = h;
        for i in 0..64 {
            let s1 = e.rotate_right(6) ^ e.rotate_right(11) ^ e.rotate_right(25);
            let ch = (e & f) ^ (!e & g);
            let t1 = hh
                .wrapping_add(s1)
                .wrapping_add(ch)
                .wrapping_add(K[i])
                .wrapping_add(w[i]);
            let s0 = a.rotate_right(2) ^ a.rotate_right(13) ^ a.rotate_right(22);
            let maj = (a & b) ^ (a & c) ^ (b & c);
            let t2 = s0.wrapping_add(maj);
            hh = g;
            g = f;
            f = e;
            e = d.wrapping_add(t1);
            d = c;
            c = b;
            b = a;
            a = t1.wrapping_add(t2);
        }
        for (x, y) in h.iter_mut().zip([a, b, c, d, e, f, g, hh]) {
            *x = x.wrapping_add(y);
        }
    }
    let mut digest = [0u8; 32];
    for (i, word) in h.iter().enumerate() {
        digest[4 * i..4 * i + 4].copy_from_slice(&word.to_be_bytes());
    }
    digest
}

/// Compares a fresh compile (and the listing of its sources) with the checked-in kernels;
/// `VKRT_KERNELS` says what to do where they differ.
#[cfg(feature = "shaderc")]
fn sync_checked_in(root: &Path, text: &str, sources: &str) {
    let files = [(CHECKED_IN, text), (SOURCES, sources)];
    let stale: Vec<&str> = files
        .iter()
        .filter(|(rel, want)| {
            std::fs::read_to_string(root.join(rel)).map_or(true, |old| old != *want)
        })
        .map(|(rel, _)| *rel)
        .collect();
    if stale.is_empty() {
        return;
    }
    match std::env::var("VKRT_KERNELS").as_deref() {
        Ok("update") => {
            std::fs::create_dir_all(root.join("kernels")).expect("cannot create kernels/");
            for (rel, want) in files {
                std::fs::write(root.join(rel), want)
                    .unwrap_or_else(|e| panic!("cannot write {rel}: {e}"));
            }
        }
        Ok("check") => panic!(
            "{} differ(s) from a fresh compile of glsl/: rebuild with VKRT_KERNELS=update and \
             commit them (dependents without the shaderc feature use them)",
            stale.join(" and ")
        ),
        _ => println!(
            "cargo:warning={} differ(s) from a fresh compile of glsl/: rebuild with \
             VKRT_KERNELS=update and commit them",
            stale.join(" and ")
        ),
    }
}

/// Compiles every kernel variant under `root/glsl` and generates `shaders.rs`.
#[cfg(feature = "shaderc")]
fn compile_all(root: &Path) -> String {
    let glsl = root.join("glsl");
    let mut files = Vec::new();
    collect_files(&glsl, &mut files);
    files.sort();
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
    }

    let compiler = shaderc::Compiler::new().expect("shaderc: cannot create a compiler");
    let mut errors = Vec::new();
    let mut blobs = Vec::new();
    for file in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "comp"))
    {
        let rel = file
            .strip_prefix(root)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let source = match std::fs::read_to_string(file) {
            Ok(s) => s,
            Err(e) => {
                errors.push(format!("{rel}: cannot read: {e}"));
                continue;
            }
        };
        let base = kernel_base_name(file.strip_prefix(&glsl).unwrap());
        for variant in parse_variants(&source, &rel, &mut errors) {
            let name = match &variant.name {
                Some(v) => format!("{base}.{v}"),
                None => base.clone(),
            };
            // `//! library`: a SPIR-V library (vkrt::spirv links its functions into other
            // modules), compiled unoptimised to SPIR-V 1.3 so that its functions stay.
            let library = source.lines().any(|l| l.trim() == "//! library");
            match compile(&compiler, &glsl, &source, &rel, &variant.defines, library) {
                Ok(words) => match reflect(&words) {
                    Ok(info) => blobs.push(Blob {
                        name,
                        source: rel.clone(),
                        defines: variant.defines.clone(),
                        words,
                        info,
                    }),
                    Err(e) => errors.push(format!("{rel} ({name}): {e}")),
                },
                Err(e) => errors.push(format!("{rel} ({name}):\n{e}")),
            }
        }
    }
    if !errors.is_empty() {
        for e in &errors {
            eprintln!("{e}\n");
        }
        panic!(
            "{} shader error(s); messages above (file:line: error: ...)",
            errors.len()
        );
    }
    generate(&blobs)
}

fn collect_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            collect_files(&path, out);
        } else {
            out.push(path);
        }
    }
}

fn kernel_base_name(rel: &Path) -> String {
    let no_ext = rel.with_extension("");
    no_ext
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join(".")
}

struct Variant {
    name: Option<String>,
    defines: Vec<(String, String)>,
}

fn parse_variants(source: &str, rel: &str, errors: &mut Vec<String>) -> Vec<Variant> {
    let mut variants = Vec::new();
    for (line_no, line) in source.lines().enumerate() {
        let Some(rest) = line.trim().strip_prefix("//! variant") else {
            continue;
        };
        let mut words = rest.split_whitespace();
        let Some(name) = words.next() else {
            errors.push(format!("{rel}:{}: `//! variant` needs a name", line_no + 1));
            continue;
        };
        if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            errors.push(format!("{rel}:{}: bad variant name `{name}`", line_no + 1));
            continue;
        }
        let defines = words
            .map(|w| match w.split_once('=') {
                Some((k, v)) => (k.to_string(), v.to_string()),
                None => (w.to_string(), "1".to_string()),
            })
            .collect();
        variants.push(Variant {
            name: Some(name.to_string()),
            defines,
        });
    }
    if variants.is_empty() {
        variants.push(Variant {
            name: None,
            defines: Vec::new(),
        });
    }
    variants
}

#[cfg(feature = "shaderc")]
fn compile(
    compiler: &shaderc::Compiler,
    glsl: &Path,
    source: &str,
    rel: &str,
    defines: &[(String, String)],
    library: bool,
) -> Result<Vec<u32>, String> {
    let mut options = shaderc::CompileOptions::new().map_err(|e| e.to_string())?;
    if library {
        options.set_target_env(
            shaderc::TargetEnv::Vulkan,
            shaderc::EnvVersion::Vulkan1_1 as u32,
        );
        options.set_target_spirv(shaderc::SpirvVersion::V1_3);
        options.set_optimization_level(shaderc::OptimizationLevel::Zero);
    } else {
        options.set_target_env(
            shaderc::TargetEnv::Vulkan,
            shaderc::EnvVersion::Vulkan1_2 as u32,
        );
        options.set_target_spirv(shaderc::SpirvVersion::V1_5);
        options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    }
    options.set_warnings_as_errors();
    for (k, v) in defines {
        options.add_macro_definition(k, Some(v));
    }
    let glsl = glsl.to_path_buf();
    options.set_include_callback(move |name, kind, requester, _depth| {
        // `#include "x"` resolves next to the requesting file first, then from glsl/.
        let mut candidates = Vec::new();
        if kind == shaderc::IncludeType::Relative {
            if let Some(dir) = Path::new(requester).parent() {
                candidates.push(dir.join(name));
            }
        }
        candidates.push(glsl.join(name));
        for path in candidates {
            if let Ok(content) = std::fs::read_to_string(&path) {
                let root = glsl.parent().unwrap();
                let shown = path.strip_prefix(root).unwrap_or(&path);
                return Ok(shaderc::ResolvedInclude {
                    resolved_name: shown.to_string_lossy().into_owned(),
                    content,
                });
            }
        }
        Err(format!(
            "cannot find include `{name}` (looked beside {requester} and in glsl/)"
        ))
    });
    let artifact = compiler
        .compile_into_spirv(
            source,
            shaderc::ShaderKind::Compute,
            rel,
            "main",
            Some(&options),
        )
        .map_err(|e| e.to_string())?;
    Ok(artifact.as_binary().to_vec())
}

#[derive(Default)]
struct Reflection {
    bindings: Vec<u32>,
    /// Of `bindings`, those that are uniform texel buffers (`samplerBuffer` and kin).
    texel_bindings: Vec<u32>,
    /// Of `bindings`, those the kernel only reads (`readonly` blocks, texel buffers).
    read_only_bindings: Vec<u32>,
    /// Of `bindings`, those the kernel only writes (`writeonly` blocks).
    write_only_bindings: Vec<u32>,
    spec_constants: Vec<(u32, u32)>,
    local_size: [u32; 3],
    local_size_spec_ids: [Option<u32>; 3],
    push_constants: bool,
}

/// A minimal SPIR-V reader: just enough to check and describe a kernel's interface.
fn reflect(words: &[u32]) -> Result<Reflection, String> {
    const OP_EXECUTION_MODE: u32 = 16;
    const OP_SPEC_CONSTANT_TRUE: u32 = 48;
    const OP_SPEC_CONSTANT_FALSE: u32 = 49;
    const OP_SPEC_CONSTANT: u32 = 50;
    const OP_SPEC_CONSTANT_COMPOSITE: u32 = 51;
    const OP_TYPE_STRUCT: u32 = 30;
    const OP_TYPE_POINTER: u32 = 32;
    const OP_VARIABLE: u32 = 59;
    const OP_DECORATE: u32 = 71;
    const OP_MEMBER_DECORATE: u32 = 72;
    const DEC_NON_WRITABLE: u32 = 24;
    const DEC_NON_READABLE: u32 = 25;
    const DEC_SPEC_ID: u32 = 1;
    const DEC_BUILTIN: u32 = 11;
    const DEC_BINDING: u32 = 33;
    const DEC_SET: u32 = 34;
    const BUILTIN_WORKGROUP_SIZE: u32 = 25;
    const MODE_LOCAL_SIZE: u32 = 17;
    const SC_UNIFORM_CONSTANT: u32 = 0;
    const SC_UNIFORM: u32 = 2;
    const SC_PUSH_CONSTANT: u32 = 9;
    const SC_STORAGE_BUFFER: u32 = 12;

    if words.len() < 5 || words[0] != 0x0723_0203 {
        return Err("not SPIR-V".into());
    }
    let mut r = Reflection::default();
    let mut binding = std::collections::HashMap::new();
    let mut set = std::collections::HashMap::new();
    let mut spec_id = std::collections::HashMap::new();
    let mut spec_default = std::collections::HashMap::new();
    let mut workgroup_size_id = None;
    let mut composites = std::collections::HashMap::new();
    let mut variables = Vec::new();
    // Access: the ids decorated NonWritable / NonReadable, the members so decorated per
    // struct, the member count of each struct and the pointee of each pointer type.
    let mut non_writable = std::collections::HashSet::new();
    let mut non_readable = std::collections::HashSet::new();
    let mut member_flags: std::collections::HashMap<u32, (usize, usize)> = Default::default();
    let mut struct_members = std::collections::HashMap::new();
    let mut pointee = std::collections::HashMap::new();
    let mut i = 5;
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let op = words[i] & 0xffff;
        if count == 0 || i + count > words.len() {
            return Err("truncated SPIR-V".into());
        }
        let w = &words[i..i + count];
        match op {
            OP_DECORATE if count >= 4 => match w[2] {
                DEC_BINDING => {
                    binding.insert(w[1], w[3]);
                }
                DEC_SET => {
                    set.insert(w[1], w[3]);
                }
                DEC_SPEC_ID => {
                    spec_id.insert(w[1], w[3]);
                }
                DEC_BUILTIN if w[3] == BUILTIN_WORKGROUP_SIZE => workgroup_size_id = Some(w[1]),
                _ => {}
            },
            OP_DECORATE if count == 3 => match w[2] {
                DEC_NON_WRITABLE => {
                    non_writable.insert(w[1]);
                }
                DEC_NON_READABLE => {
                    non_readable.insert(w[1]);
                }
                _ => {}
            },
            OP_MEMBER_DECORATE if count >= 4 => {
                let flags = member_flags.entry(w[1]).or_default();
                match w[3] {
                    DEC_NON_WRITABLE => flags.0 += 1,
                    DEC_NON_READABLE => flags.1 += 1,
                    _ => {}
                }
            }
            OP_TYPE_STRUCT if count >= 2 => {
                struct_members.insert(w[1], count - 2);
            }
            OP_TYPE_POINTER if count >= 4 => {
                pointee.insert(w[1], w[3]);
            }
            OP_EXECUTION_MODE if count >= 6 && w[2] == MODE_LOCAL_SIZE => {
                r.local_size = [w[3], w[4], w[5]];
            }
            OP_SPEC_CONSTANT if count >= 4 => {
                spec_default.insert(w[2], w[3]);
            }
            OP_SPEC_CONSTANT_TRUE | OP_SPEC_CONSTANT_FALSE if count >= 3 => {
                spec_default.insert(w[2], u32::from(op == OP_SPEC_CONSTANT_TRUE));
            }
            OP_SPEC_CONSTANT_COMPOSITE if count >= 6 => {
                composites.insert(w[2], [w[3], w[4], w[5]]);
            }
            OP_VARIABLE if count >= 4 => variables.push((w[1], w[2], w[3])),
            _ => {}
        }
        i += count;
    }
    // Per binding: (every block on it read-only, every block on it write-only).
    let mut access: std::collections::HashMap<u32, (bool, bool)> = Default::default();
    for (ty, id, class) in variables {
        match class {
            SC_STORAGE_BUFFER => {
                if set.get(&id).copied().unwrap_or(0) != 0 {
                    return Err("only descriptor set 0 is supported".into());
                }
                let b = *binding.get(&id).ok_or("storage buffer without a binding")?;
                r.bindings.push(b);
                // A block is read-only (write-only) when the variable, or every member of
                // its struct, is decorated so.
                let block = pointee.get(&ty).copied().unwrap_or(0);
                let members = struct_members.get(&block).copied().unwrap_or(usize::MAX);
                let (nw, nr) = member_flags.get(&block).copied().unwrap_or((0, 0));
                let read_only = non_writable.contains(&id) || nw == members;
                let write_only = non_readable.contains(&id) || nr == members;
                let a = access.entry(b).or_insert((true, true));
                *a = (a.0 && read_only, a.1 && write_only);
            }
            SC_PUSH_CONSTANT => r.push_constants = true,
            // A `uniform utextureBuffer` (and kin): read through the sampler path.
            SC_UNIFORM_CONSTANT if binding.contains_key(&id) => {
                if set.get(&id).copied().unwrap_or(0) != 0 {
                    return Err("only descriptor set 0 is supported".into());
                }
                let b = binding[&id];
                r.bindings.push(b);
                r.texel_bindings.push(b);
                let a = access.entry(b).or_insert((true, true));
                *a = (a.0, false);
            }
            SC_UNIFORM if binding.contains_key(&id) => {
                return Err(
                    "kernels may bind only storage buffers (std430 `buffer` blocks) and \
                     texel buffers"
                        .into(),
                );
            }
            _ => {}
        }
    }
    r.bindings.sort_unstable();
    // Blocks that alias one binding (traverse.glsl's kd-tree and BVH nodes) bind one buffer.
    r.bindings.dedup();
    r.texel_bindings.sort_unstable();
    r.texel_bindings.dedup();
    for &b in &r.bindings {
        match access.get(&b) {
            Some((true, _)) => r.read_only_bindings.push(b),
            Some((false, true)) => r.write_only_bindings.push(b),
            _ => {}
        }
    }
    for (id, sid) in &spec_id {
        let default = spec_default.get(id).copied().unwrap_or(0);
        r.spec_constants.push((*sid, default));
    }
    r.spec_constants.sort_unstable();
    if let Some(wg) = workgroup_size_id {
        if let Some(parts) = composites.get(&wg) {
            for (axis, part) in parts.iter().enumerate() {
                if let Some(sid) = spec_id.get(part) {
                    r.local_size_spec_ids[axis] = Some(*sid);
                    r.local_size[axis] = spec_default.get(part).copied().unwrap_or(1);
                }
            }
        }
    }
    Ok(r)
}

struct Blob {
    name: String,
    source: String,
    defines: Vec<(String, String)>,
    words: Vec<u32>,
    info: Reflection,
}

fn generate(blobs: &[Blob]) -> String {
    let mut s = String::from("// Generated by build.rs from glsl/. Do not edit.\n\n");
    for b in blobs {
        let ident = rust_ident(&b.name);
        let _ = writeln!(s, "/// `{}` compiled from `{}`.", b.name, b.source);
        let _ = writeln!(s, "pub static {ident}: ShaderBlob = ShaderBlob {{");
        let _ = writeln!(s, "    name: {:?},", b.name);
        let _ = writeln!(s, "    source: {:?},", b.source);
        let _ = writeln!(
            s,
            "    defines: &{:?},",
            b.defines
                .iter()
                .map(|(k, v)| (k.as_str(), v.as_str()))
                .collect::<Vec<_>>()
        );
        let _ = writeln!(s, "    bindings: &{:?},", b.info.bindings);
        let _ = writeln!(s, "    texel_bindings: &{:?},", b.info.texel_bindings);
        let _ = writeln!(
            s,
            "    read_only_bindings: &{:?},",
            b.info.read_only_bindings
        );
        let _ = writeln!(
            s,
            "    write_only_bindings: &{:?},",
            b.info.write_only_bindings
        );
        let _ = writeln!(s, "    spec_constants: &{:?},", b.info.spec_constants);
        let _ = writeln!(s, "    local_size: {:?},", b.info.local_size);
        let _ = writeln!(
            s,
            "    local_size_spec_ids: {:?},",
            b.info.local_size_spec_ids
        );
        let _ = writeln!(s, "    push_constants: {},", b.info.push_constants);
        s.push_str("    spirv: &[");
        for (i, w) in b.words.iter().enumerate() {
            if i % 8 == 0 {
                s.push_str("\n        ");
            }
            let _ = write!(s, "{w:#010x}, ");
        }
        s.push_str("\n    ],\n};\n\n");
    }
    s.push_str("/// Every kernel variant, sorted by name.\npub static ALL: &[&ShaderBlob] = &[\n");
    let mut names: Vec<_> = blobs.iter().map(|b| &b.name).collect();
    names.sort();
    for n in names {
        let ident = rust_ident(n);
        let _ = writeln!(s, "    &{ident},");
    }
    s.push_str("];\n");
    s
}

fn rust_ident(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_uppercase()
            } else {
                '_'
            }
        })
        .collect()
}
