//! Measured baselines for `vkrt bench`: what moving the same bytes costs on this device.
//!
//! Every kernel in vkrt is reported as a ratio to these, measured in the same run:
//! `vkCmdCopyBuffer` (the driver's copy; memcpy on lavapipe) and the best plain copy
//! kernel (u32 or uvec4 per invocation, several workgroup sizes). Buffers are touched
//! once before timing: the first touch of fresh memory on lavapipe costs page faults.

use serde::Serialize;

use crate::gpu::{kernels, Buffer, Context, Profile, Recorder, Result, Spec};

/// One timed variant of a copy.
#[derive(Clone, Debug, Serialize)]
pub struct CopyResult {
    pub method: String,
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
    pub device: String,
    pub subgroup_size: u32,
    pub bytes: u64,
    pub repetitions: u32,
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

type KernelVariant = (std::sync::Arc<crate::gpu::Kernel>, u32);

const WORKGROUP_SIZES: [u32; 3] = [64, 256, 1024];

/// Measures `vkCmdCopyBuffer` and the copy kernels over `bytes`, `reps` times each, and
/// returns the baselines plus the profile of every timed pass.
pub fn copy_baselines(ctx: &Context, bytes: u64, reps: u32) -> Result<(CopyBaselines, Profile)> {
    let words = (bytes / 16 * 4) as usize;
    let bytes = words as u64 * 4;
    let src = Buffer::<u32>::new(ctx, "bench.src", words)?;
    let dst = Buffer::<u32>::new(ctx, "bench.dst", words)?;
    // (name, None = vkCmdCopyBuffer | Some((kernel, u32 words per invocation)))
    let mut variants: Vec<(String, Option<KernelVariant>)> =
        vec![("vkCmdCopyBuffer".to_string(), None)];
    for wg in WORKGROUP_SIZES
        .into_iter()
        .filter(|&w| w <= ctx.info().max_workgroup_invocations)
    {
        let spec = Spec::new().workgroup(wg);
        variants.push((
            format!("copy_kernel.u32.wg{wg}"),
            Some((ctx.kernel(&kernels::GPU_COPY_U32, &spec)?, 1)),
        ));
        variants.push((
            format!("copy_kernel.uvec4.wg{wg}"),
            Some((ctx.kernel(&kernels::GPU_COPY_UVEC4, &spec)?, 4)),
        ));
    }
    let mut rec = Recorder::new(ctx)?;
    // Warm-up: touch every page of both buffers once, untimed.
    rec.fill(&src, 0x1234_5678);
    rec.fill(&dst, 0);
    rec.transfer_to_transfer();
    for rep in 0..=reps {
        for (name, kernel) in &variants {
            let label = if rep == 0 {
                format!("warmup.{name}")
            } else {
                name.clone()
            };
            rec.begin_scope(&label);
            match kernel {
                None => rec.copy(&src, &dst, words),
                Some((k, per)) => {
                    let n = (words / *per as usize) as u32;
                    let groups = rec.groups_1d(u64::from(n), k.invocations());
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
    let best = |name: &str| {
        profile
            .passes
            .iter()
            .filter(|p| p.name == name)
            .filter_map(|p| p.ms)
            .fold(f64::INFINITY, f64::min)
    };
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
