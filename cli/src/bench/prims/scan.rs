//! `scan_u32*` and `flag_scan*`: [`vkrt::prims::scan::Scan`] in every variant over several
//! workgroup shapes.

use vkrt::gpu::{Buffer, BufferArg, Context, Recorder, Result};
use vkrt::prims::scan::{Scan, ScanInput, ScanOp, ScanVariant};
use vkrt::prims::PrimConfig;

use super::PrimTiming;
use crate::bench::{best_ms, rep_scope};

/// Times the scans at `n` elements: u32 with `subgroupInclusiveAdd` and with shuffles, for
/// several items per invocation ("algorithm cascading"), and the flag scan.
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let base = PrimConfig::default_for(ctx);
    let words = Buffer::<u32>::new(ctx, "bench.scan.in", n)?;
    let flags = Buffer::<u8>::new(ctx, "bench.scan.flags", n)?;
    let out = Buffer::<u32>::new(ctx, "bench.scan.out", n)?;
    let mut variants: Vec<(String, Scan, bool)> = Vec::new();
    let sg = ctx.info().subgroup_size;
    let shapes = [
        (sg, 4),
        (sg, 16),
        (64, 16),
        (256, 4),
        (256, 16),
        (256, 32),
        (1024, 16),
    ];
    for (wg, ipi) in shapes {
        let cfg = PrimConfig {
            workgroup_size: wg.max(sg),
            items_per_invocation: ipi,
        };
        let suffix = if cfg == base {
            String::new()
        } else {
            format!(".wg{wg}.ipi{ipi}")
        };
        variants.push((
            format!("scan_u32{suffix}"),
            Scan::new(ctx, cfg, ScanInput::U32)?,
            false,
        ));
        variants.push((
            format!("scan_u32_shuffle{suffix}"),
            Scan::with_shuffle(ctx, cfg)?,
            false,
        ));
        let contiguous = ScanVariant::Contiguous;
        variants.push((
            format!("scan_u32_contiguous{suffix}"),
            Scan::with_variant(ctx, cfg, ScanInput::U32, contiguous)?,
            false,
        ));
        variants.push((
            format!("flag_scan{suffix}"),
            Scan::new(ctx, cfg, ScanInput::Flags)?,
            true,
        ));
        variants.push((
            format!("flag_scan_contiguous{suffix}"),
            Scan::with_variant(ctx, cfg, ScanInput::Flags, contiguous)?,
            true,
        ));
    }
    let scratches = variants
        .iter()
        .map(|(_, s, _)| s.scratch(ctx, n))
        .collect::<Result<Vec<_>>>()?;
    let mut rec = Recorder::new(ctx)?;
    rec.fill(&words, 1);
    rec.fill(&flags, 0x0001_0001);
    rec.fill(&out, 0);
    rec.transfer_to_compute();
    for rep in 0..=reps {
        for ((name, scan, is_flags), scratch) in variants.iter().zip(&scratches) {
            let input: &dyn BufferArg = if *is_flags { &flags } else { &words };
            rec.scope(&rep_scope(rep, name), |rec| {
                scan.record(rec, input, &out, n, ScanOp::Exclusive, scratch)
            });
            rec.compute_to_compute();
        }
    }
    let profile = rec.submit_and_wait()?;
    Ok(variants
        .iter()
        .map(|(name, _, is_flags)| PrimTiming {
            prim: name.clone(),
            n: n as u64,
            gpu_ms: best_ms(&profile, name),
            min_bytes: if *is_flags {
                5 * n as u64
            } else {
                8 * n as u64
            },
        })
        .collect())
}
