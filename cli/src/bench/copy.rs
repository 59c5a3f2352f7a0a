//! Measured baselines for `vkrt bench`: what moving the same bytes costs on this device.
//!
//! Every kernel in vkrt is reported as a ratio to these, measured in the same run:
//! `vkCmdCopyBuffer` (the driver's copy; memcpy on lavapipe) and the best plain copy
//! kernel (u32, uvec4 or u64vec4 granules, one or four per invocation, several workgroup
//! sizes; the 64-bit ones only where the device has shaderInt64). Buffers are touched
//! once before timing: the first touch of fresh memory on lavapipe costs page faults.

use serde::Serialize;

use vkrt::gpu::{kernels, Buffer, Context, Profile, Recorder, Result, Spec};

use super::{best_ms, rep_scope};

/// One timed variant of a copy.
#[derive(Clone, Debug, Serialize)]
pub struct CopyResult {
    /// `vkCmdCopyBuffer`, or `copy_kernel.<granule>.wg<workgroup size>`.
    pub method: String,
    /// Bytes copied (read, and as many written).
    pub bytes: u64,
    /// Best of the timed repetitions, milliseconds of GPU time.
    pub gpu_ms: f64,
    /// Bytes read plus bytes written, GiB per second.
    pub gib_per_s: f64,
    /// `copy_ms / gpu_ms` of `vkCmdCopyBuffer` in the same run (1.0 = as fast).
    pub ratio_to_copy: f64,
}

/// The copy baselines for `bytes` bytes (rounded down to a multiple of 16).
#[derive(Clone, Debug, Serialize)]
pub struct CopyBaselines {
    /// The device name the driver reports.
    pub device: String,
    /// The device's default subgroup size (invocations).
    pub subgroup_size: u32,
    /// Bytes each variant copies.
    pub bytes: u64,
    /// Timed repetitions of each variant (after one untimed warm-up).
    pub repetitions: u32,
    /// `vkCmdCopyBuffer` first, then each copy kernel the device can run at each workgroup
    /// size it allows.
    pub results: Vec<CopyResult>,
}

impl CopyBaselines {
    /// The fastest copy kernel.
    pub fn best_kernel(&self) -> Option<&CopyResult> {
        self.results
            .iter()
            .filter(|r| r.method != "vkCmdCopyBuffer")
            .min_by(|a, b| a.gpu_ms.total_cmp(&b.gpu_ms))
    }
}

/// A copy kernel, its u32 words per element (its `ELEM`) and elements per invocation.
type KernelVariant = (std::sync::Arc<vkrt::gpu::Kernel>, u32, u32);

const WORKGROUP_SIZES: [u32; 3] = [64, 256, 1024];

/// The copy kernels: (name, blob, u32 words per element, elements per invocation, needs
/// shaderInt64).
const COPY_KERNELS: [(&str, &vkrt::gpu::ShaderBlob, u32, u32, bool); 6] = [
    ("u32", &kernels::GPU_COPY_U32, 1, 1, false),
    ("uvec4", &kernels::GPU_COPY_UVEC4, 4, 1, false),
    ("uvec4x4", &kernels::GPU_COPY_UVEC4X4, 4, 4, false),
    ("u64vec4", &kernels::GPU_COPY_U64VEC4, 8, 1, true),
    ("u64vec4x4", &kernels::GPU_COPY_U64VEC4X4, 8, 4, true),
    ("u64vec4run16", &kernels::GPU_COPY_U64VEC4RUN16, 8, 16, true),
];

/// Measures `vkCmdCopyBuffer` and the copy kernels over `bytes`, `reps` times each, and
/// returns the baselines plus the profile of every timed pass.
pub fn copy_baselines(ctx: &Context, bytes: u64, reps: u32) -> Result<(CopyBaselines, Profile)> {
    measure(ctx, bytes, reps, true, |_, _| true)
}

/// The best copy kernel's bandwidth (read plus written GiB/s) over 32 MiB, from the
/// variants that are fastest on lavapipe (workgroups of 256, four uvec4 or sixteen
/// u64vec4 per invocation), each run three times: the baseline `--profile-stats` weighs
/// every pass's bytes against, in a fraction of `vkrt bench copy`'s time.
pub fn copy_bandwidth(ctx: &Context) -> Result<f64> {
    let (baselines, _) = measure(ctx, 32 << 20, 3, false, |name, wg| {
        wg == 256 && matches!(name, "uvec4x4" | "u64vec4run16")
    })?;
    Ok(baselines.best_kernel().map_or(0.0, |r| r.gib_per_s))
}

/// Times `vkCmdCopyBuffer` (with `driver_copy`) and the copy kernels `keep(name,
/// workgroup size)` selects.
fn measure(
    ctx: &Context,
    bytes: u64,
    reps: u32,
    driver_copy: bool,
    keep: impl Fn(&str, u32) -> bool,
) -> Result<(CopyBaselines, Profile)> {
    // A whole number of the widest kernel's invocations (32 words).
    let words = (bytes / 128 * 32).max(32) as usize;
    let bytes = words as u64 * 4;
    let src = Buffer::<u32>::new(ctx, "bench.src", words)?;
    let dst = Buffer::<u32>::new(ctx, "bench.dst", words)?;
    // (name, None = vkCmdCopyBuffer | Some(kernel variant))
    let mut variants: Vec<(String, Option<KernelVariant>)> = Vec::new();
    if driver_copy {
        variants.push(("vkCmdCopyBuffer".to_string(), None));
    }
    for wg in WORKGROUP_SIZES
        .into_iter()
        .filter(|&w| w <= ctx.info().max_workgroup_invocations)
    {
        let spec = Spec::new().workgroup(wg);
        for (name, blob, words_per_elem, per_invocation, int64) in COPY_KERNELS {
            if int64 && !ctx.info().features.shader_int64 || !keep(name, wg) {
                continue;
            }
            variants.push((
                format!("copy_kernel.{name}.wg{wg}"),
                Some((ctx.kernel(blob, &spec)?, words_per_elem, per_invocation)),
            ));
        }
    }
    let mut rec = Recorder::new(ctx)?;
    // Warm-up: touch every page of both buffers once, untimed.
    rec.fill(&src, 0x1234_5678);
    rec.fill(&dst, 0);
    rec.transfer_to_transfer();
    for rep in 0..=reps {
        for (name, kernel) in &variants {
            rec.begin_scope(&rep_scope(rep, name));
            match kernel {
                None => rec.copy(&src, &dst, words),
                Some((k, words_per_elem, per_invocation)) => {
                    let n = (words / *words_per_elem as usize) as u32;
                    let invocations = n.div_ceil(*per_invocation);
                    let groups = rec.groups_1d(u64::from(invocations), k.invocations());
                    rec.dispatch(k, groups, &[&src, &dst], &n);
                }
            }
            rec.end_scope();
            // Each copy writes `dst`: order them so timings never overlap.
            rec.compute_to_transfer();
            rec.transfer_to_compute();
            rec.compute_to_compute();
            rec.transfer_to_transfer();
        }
    }
    let profile = rec.submit_and_wait()?;
    let best = |name: &str| best_ms(&profile, name);
    let copy_ms = best("vkCmdCopyBuffer");
    let results = variants
        .iter()
        .map(|(name, _)| {
            let ms = best(name);
            CopyResult {
                method: name.clone(),
                bytes,
                gpu_ms: ms,
                gib_per_s: 2.0 * bytes as f64 / (ms / 1e3) / f64::from(1u32 << 30),
                ratio_to_copy: copy_ms / ms,
            }
        })
        .collect();
    let baselines = CopyBaselines {
        device: ctx.info().device.clone(),
        subgroup_size: ctx.info().subgroup_size,
        bytes,
        repetitions: reps,
        results,
    };
    Ok((baselines, profile))
}
