//! The GPU primitives' benchmarks, one module a primitive: each times its variants at `n`
//! elements through the library's public API (the best of `reps` after one untimed
//! warm-up) and names them as `vkrt bench prims` reports them.

pub mod compact;
pub mod radix_sort;
pub mod reduce;
pub mod scan;
pub mod segmented;

use serde::Serialize;

use vkrt::gpu::{Context, Result};

use super::copy::copy_baselines;

/// One primitive timed on the GPU, for `vkrt bench prims`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PrimTiming {
    /// The primitive's name (e.g. `scan_u32`, `compact_4_arrays`).
    pub prim: String,
    /// Elements processed.
    pub n: u64,
    /// GPU milliseconds of the primitive's passes (best of the repetitions).
    pub gpu_ms: f64,
    /// Bytes the primitive must at least read plus write (the copy baselines move as much).
    pub min_bytes: u64,
}

/// One row of `vkrt bench prims --json`.
#[derive(Clone, Debug, Serialize)]
pub struct PrimResult {
    /// The primitive's name (e.g. `scan_u32`, `compact_4_arrays`).
    pub prim: String,
    /// Elements processed.
    pub n: u64,
    /// GPU milliseconds of the primitive's passes (best of the repetitions).
    pub gpu_ms: f64,
    /// `n` over `gpu_ms`, elements per second.
    pub elements_per_s: f64,
    /// Bytes the primitive must at least read plus write.
    pub min_bytes: u64,
    /// `vkCmdCopyBuffer` of `min_bytes / 2` bytes (it reads and writes as much).
    pub copy_ms: f64,
    /// The best plain copy kernel on the same bytes.
    pub copy_kernel_ms: f64,
    /// `copy_ms / gpu_ms`: 1.0 = as fast as the driver's copy of the same bytes.
    pub ratio_to_copy: f64,
    /// `copy_kernel_ms / gpu_ms`: 1.0 = as fast as the best copy kernel.
    pub ratio_to_copy_kernel: f64,
}

/// `vkrt bench prims --json`.
#[derive(Clone, Debug, Serialize)]
pub struct PrimsReport {
    /// The device name the driver reports.
    pub device: String,
    /// The device's default subgroup size (invocations).
    pub subgroup_size: u32,
    /// One row per primitive and size.
    pub results: Vec<PrimResult>,
}

/// A primitive's benchmark: times at `n` elements, best of `reps`.
pub type PrimBench = fn(&Context, usize, u32) -> Result<Vec<PrimTiming>>;

/// Every primitive's benchmark, in the order of the report.
pub fn prim_benches() -> Vec<(&'static str, PrimBench)> {
    vec![
        ("scan", scan::bench as PrimBench),
        ("compact", compact::bench),
        ("reduce", reduce::bench),
        ("segmented", segmented::bench),
        // Its rows include `cpu_sort_unstable_by_key`: the CPU sort of the same pairs on one
        // core (its "gpu_ms" is CPU wall time).
        ("radix", radix_sort::bench),
    ]
}

/// Times every primitive at each of `sizes` and sets each against the copy baselines of
/// the same bytes, measured in the same run. `only` keeps the benches whose group name
/// contains it.
pub fn prims_report(
    ctx: &Context,
    sizes: &[usize],
    reps: u32,
    only: Option<&str>,
) -> Result<PrimsReport> {
    let mut results = Vec::new();
    let mut baselines: std::collections::HashMap<u64, (f64, f64)> = Default::default();
    for &n in sizes {
        for (group, bench) in prim_benches() {
            if only.is_some_and(|o| !group.contains(o)) {
                continue;
            }
            for t in bench(ctx, n, reps)? {
                let copy_bytes = (t.min_bytes / 2).max(16);
                let (copy_ms, copy_kernel_ms) = match baselines.get(&copy_bytes) {
                    Some(&b) => b,
                    None => {
                        // Above the largest buffer, time the largest and scale linearly
                        // (copies are bandwidth-bound at that size).
                        let cap = ctx.info().max_storage_buffer_range / 16 * 16;
                        let measured = copy_bytes.min(cap);
                        let scale = copy_bytes as f64 / measured as f64;
                        let (b, _) = copy_baselines(ctx, measured, reps)?;
                        let copy = b
                            .results
                            .iter()
                            .find(|r| r.method == "vkCmdCopyBuffer")
                            .map_or(f64::NAN, |r| r.gpu_ms * scale);
                        let kernel = b.best_kernel().map_or(f64::NAN, |r| r.gpu_ms * scale);
                        baselines.insert(copy_bytes, (copy, kernel));
                        (copy, kernel)
                    }
                };
                results.push(PrimResult {
                    elements_per_s: t.n as f64 / (t.gpu_ms / 1e3),
                    ratio_to_copy: copy_ms / t.gpu_ms,
                    ratio_to_copy_kernel: copy_kernel_ms / t.gpu_ms,
                    prim: t.prim,
                    n: t.n,
                    gpu_ms: t.gpu_ms,
                    min_bytes: t.min_bytes,
                    copy_ms,
                    copy_kernel_ms,
                });
            }
        }
    }
    Ok(PrimsReport {
        device: ctx.info().device.clone(),
        subgroup_size: ctx.info().subgroup_size,
        results,
    })
}
