//! The SPIR-V pass's cost: each of the repository's ray-query shaders (`examples/ray_queries`,
//! compiled by glslc for the driver's ray query) lowered by `vkrt::spirv::lower_ray_queries`,
//! against a parse and re-assembly of the same module with the same SPIR-V library (rspirv):
//! the pass's warm time, its ratio to that baseline, the first lowering of the process apart
//! (it parses vkrt's library once), the words in and out, and the most memory a lowering
//! holds at once (a counting allocator).
//!
//! `cargo bench --bench spirv_lower [-- --json] [-- --quick]`

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rspirv::binary::Assemble;
use vkrt::spirv::{lower_ray_queries, LowerOptions};

#[path = "common/args.rs"]
mod args;

/// The system allocator, counting the bytes live and their peak.
struct Counting;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded to the system allocator with the caller's layout.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: `p` came from `alloc` with this layout.
        unsafe { System.dealloc(p, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[derive(serde::Serialize)]
struct Row {
    shader: String,
    words_in: usize,
    words_out: usize,
    functions_linked: usize,
    /// The first lowering of the process (the library parsed), ms.
    first_ms: f64,
    /// The median of the warm lowerings, ms.
    lower_ms: f64,
    /// The median of a parse and re-assembly of the input, ms.
    copy_ms: f64,
    lower_over_copy: f64,
    /// The most bytes a warm lowering held at once beyond what was live before it.
    peak_bytes: usize,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn compile(path: &std::path::Path) -> Vec<u32> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = std::env::temp_dir().join(format!("vkrt-bench-lower-{}.spv", std::process::id()));
    let status = std::process::Command::new(vkrt::shader_check::compile::compiler())
        .args([
            "--target-env=vulkan1.2",
            "-fshader-stage=compute",
            "-DVKRT_NATIVE_RAY_QUERY=1",
            "-I",
        ])
        .arg(root.join("glsl/include"))
        .arg("-o")
        .arg(&out)
        .arg(path)
        .status()
        .expect("glslc (./x setup installs it)");
    assert!(status.success(), "{}", path.display());
    let bytes = std::fs::read(&out).unwrap();
    let _ = std::fs::remove_file(&out);
    bytemuck::pod_collect_to_vec(&bytes)
}

fn main() {
    let args::BenchArgs { json, quick, .. } = args::parse();
    let reps = if quick { 5 } else { 31 };
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut shaders: Vec<_> = std::fs::read_dir(root.join("examples/ray_queries"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "comp"))
        .collect();
    shaders.sort();
    let options = LowerOptions::default();
    let mut rows = Vec::new();
    let mut first = true;
    for path in &shaders {
        let words = compile(path);
        let start = Instant::now();
        let lowered = lower_ray_queries(&words, &options).unwrap();
        let first_ms = start.elapsed().as_secs_f64() * 1e3;
        if !lowered.changed {
            continue;
        }
        let mut lower = Vec::new();
        let mut copy = Vec::new();
        let mut peak = 0;
        for _ in 0..reps {
            let before = LIVE.load(Ordering::Relaxed);
            PEAK.store(before, Ordering::Relaxed);
            let t = Instant::now();
            let out = lower_ray_queries(&words, &options).unwrap();
            lower.push(t.elapsed().as_secs_f64() * 1e3);
            peak = peak.max(PEAK.load(Ordering::Relaxed) - before);
            drop(out);
            let t = Instant::now();
            let module = rspirv::dr::load_words(&words).unwrap();
            let again = module.assemble();
            copy.push(t.elapsed().as_secs_f64() * 1e3);
            assert_eq!(again.len(), words.len());
        }
        let (lower_ms, copy_ms) = (median(lower), median(copy));
        rows.push(Row {
            shader: path.file_name().unwrap().to_string_lossy().into_owned(),
            words_in: words.len(),
            words_out: lowered.words.len(),
            functions_linked: lowered.functions_linked,
            first_ms: if first { first_ms } else { f64::NAN },
            lower_ms,
            copy_ms,
            lower_over_copy: lower_ms / copy_ms,
            peak_bytes: peak,
        });
        first = false;
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows).unwrap());
        return;
    }
    println!("shader                   words in → out     linked  first ms  lower ms  copy ms  ÷copy  peak KiB");
    for r in &rows {
        println!(
            "{:<24} {:>6} → {:<7} {:>6}  {:>8.2}  {:>8.3}  {:>7.4}  {:>5.0}  {:>8.0}",
            r.shader,
            r.words_in,
            r.words_out,
            r.functions_linked,
            r.first_ms,
            r.lower_ms,
            r.copy_ms,
            r.lower_over_copy,
            r.peak_bytes as f64 / 1024.0
        );
    }
}
