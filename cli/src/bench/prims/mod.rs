//! The GPU primitives' benchmarks, one module a primitive: each times its variants at `n`
//! elements through the library's public API (the best of `reps` after one untimed
//! warm-up) and names them as `vkrt bench prims` reports them.

pub mod compact;
pub mod radix_sort;
pub mod reduce;
pub mod scan;
pub mod segmented;

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
