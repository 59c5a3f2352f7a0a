//! `segmented_argmin.*`: [`vkrt::prims::segmented::SegmentedArgmin`] on the levels of a
//! balanced kd-tree, in each mode.

use vkrt::gpu::{Buffer, Context, Recorder, Result};
use vkrt::prims::reduce::CostIndex;
use vkrt::prims::segmented::{level_offsets, SegmentedArgmin, SegmentedMode};

use super::PrimTiming;
use crate::bench::{best_ms, rep_scope};

/// Times `modes` (label, mode) at `n` costs on kd-tree-like levels (level k: 2^k equal
/// segments) for k in `levels`, best of `reps` after one untimed warm-up, interleaved so
/// machine load affects them alike. Names are `segmented_argmin.{label}.level{k}`;
/// `min_bytes` = costs and offsets read, winners written.
pub fn bench_levels(
    ctx: &Context,
    seg: &SegmentedArgmin,
    n: usize,
    reps: u32,
    levels: &[u32],
    modes: &[(String, SegmentedMode)],
) -> Result<Vec<PrimTiming>> {
    let n32 = u32::try_from(n).expect("bench size fits u32");
    let max_level = levels.iter().copied().max().unwrap_or(0);
    let max_segments = 1u32 << max_level;
    let costs: Vec<f32> = (0..n32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 8) as f32)
        .collect();
    let costs = Buffer::from_slice(ctx, "bench.segmented.costs", &costs)?;
    let scratch = Buffer::<u32>::new(
        ctx,
        "bench.segmented.scratch",
        seg.scratch_len(n, max_segments as usize),
    )?;
    let out = Buffer::<CostIndex>::new(ctx, "bench.segmented.out", max_segments as usize)?;
    let mut inputs = Vec::new();
    for &level in levels {
        let offsets = level_offsets(n32, level);
        let count = offsets.len() as u32 - 1;
        inputs.push((
            level,
            count,
            Buffer::from_slice(ctx, "bench.segmented.offsets", &offsets)?,
            Buffer::from_slice(ctx, "bench.segmented.count", &[count])?,
        ));
    }
    let name = |label: &str, level: u32| format!("segmented_argmin.{label}.level{level}");
    let mut rec = Recorder::new(ctx)?;
    for rep in 0..=reps {
        for (level, count, offsets, count_buf) in &inputs {
            for (label, mode) in modes {
                rec.scope(&rep_scope(rep, &name(label, *level)), |rec| {
                    seg.record(
                        rec, *mode, &costs, offsets, count_buf, *count, &scratch, &out,
                    )
                });
                rec.compute_to_indirect();
            }
        }
    }
    let profile = rec.submit_and_wait()?;
    let mut timings = Vec::new();
    for (level, count, _, _) in &inputs {
        for (label, _) in modes {
            let scope = name(label, *level);
            timings.push(PrimTiming {
                gpu_ms: best_ms(&profile, &scope),
                prim: scope,
                n: n as u64,
                min_bytes: 4 * n as u64 + 4 * (u64::from(*count) + 1) + 8 * u64::from(*count),
            });
        }
    }
    Ok(timings)
}

/// Times the three modes at `n` costs on kd-tree levels 0, 4, 8, 12 and 16 (see
/// [`bench_levels`]) with [`SegmentedArgmin::recommended`]: `segmented_argmin.hybrid`
/// (this device's threshold, [`SegmentedMode::hybrid_for`]),
/// `segmented_argmin.workgroup_per_segment` and `segmented_argmin.device_wide`.
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let seg = SegmentedArgmin::recommended(ctx)?;
    let modes = [
        ("hybrid".to_string(), SegmentedMode::hybrid_for(ctx)),
        (
            "workgroup_per_segment".to_string(),
            SegmentedMode::WorkgroupPerSegment,
        ),
        ("device_wide".to_string(), SegmentedMode::DeviceWide),
    ];
    bench_levels(ctx, &seg, n, reps, &[0, 4, 8, 12, 16], &modes)
}
