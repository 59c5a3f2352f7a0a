//! Scans, flag scans and compaction against their CPU twins, bit for bit, at every edge
//! size, with a one-subgroup workgroup (subgroup-local paths) and a several-subgroup one
//! (cross-subgroup paths), under validation and synchronization validation.

mod common;

use vkrt::gpu::Context;
use vkrt::prims::compact::{compact_cpu, Compact};
use vkrt::prims::scan::{flag_scan_cpu, scan_cpu, Scan, ScanInput, ScanOp, ScanVariant};
use vkrt::prims::PrimConfig;

fn configs(ctx: &Context) -> [PrimConfig; 2] {
    [
        PrimConfig::single_subgroup(ctx),
        PrimConfig::default_for(ctx),
    ]
}

/// Inputs of one size: random over the full range (sums wrap), all equal, sorted, reversed.
fn u32_inputs(n: usize, rng: &mut common::Rng) -> Vec<(&'static str, Vec<u32>)> {
    vec![
        ("random", (0..n).map(|_| rng.next_u64() as u32).collect()),
        (
            "small",
            (0..n).map(|_| (rng.next_u64() % 4) as u32).collect(),
        ),
        ("all-equal", vec![7; n]),
        ("sorted", (0..n as u32).collect()),
        ("reverse", (0..n as u32).rev().collect()),
    ]
}

fn flag_inputs(n: usize, rng: &mut common::Rng) -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("half", (0..n).map(|_| (rng.next_u64() & 1) as u8).collect()),
        (
            "sparse",
            (0..n).map(|_| u8::from(rng.next_u64() % 97 == 0)).collect(),
        ),
        ("none", vec![0; n]),
        ("all", vec![1; n]),
    ]
}

#[test]
fn u32_scan_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(1);
    for cfg in configs(&ctx) {
        let scan = Scan::new(&ctx, cfg, ScanInput::U32).unwrap();
        let tile = scan.tile_elements();
        for n in common::edge_sizes(
            ctx.info().subgroup_size as usize,
            cfg.workgroup_size as usize,
            tile,
        ) {
            let big = n > 1 << 20;
            for (what, input) in u32_inputs(n, &mut rng)
                .into_iter()
                .take(if big { 1 } else { 5 })
            {
                for op in [ScanOp::Inclusive, ScanOp::Exclusive] {
                    let (gpu, gpu_total) = scan.run_u32(&ctx, &input, op).unwrap();
                    let (cpu, cpu_total) = scan_cpu(&input, op);
                    let diff = gpu.iter().zip(&cpu).position(|(g, c)| g != c);
                    assert_eq!(diff, None, "{cfg:?} n={n} {what} {op:?}: first difference");
                    assert_eq!(gpu.len(), n);
                    assert_eq!(gpu_total, cpu_total, "{cfg:?} n={n} {what} {op:?}: total");
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn shuffle_scan_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(2);
    for cfg in configs(&ctx) {
        let scan = Scan::with_shuffle(&ctx, cfg).unwrap();
        for n in common::edge_sizes(
            ctx.info().subgroup_size as usize,
            cfg.workgroup_size as usize,
            cfg.tile() as usize,
        ) {
            let input: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
            let (gpu, total) = scan.run_u32(&ctx, &input, ScanOp::Inclusive).unwrap();
            assert!(
                (gpu, total) == scan_cpu(&input, ScanOp::Inclusive),
                "{cfg:?} n={n}"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn flag_scan_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(3);
    for cfg in configs(&ctx) {
        let scan = Scan::new(&ctx, cfg, ScanInput::Flags).unwrap();
        let tile = scan.tile_elements();
        let mut sizes = common::edge_sizes(
            ctx.info().subgroup_size as usize,
            cfg.workgroup_size as usize,
            tile,
        );
        sizes.extend([2, 3, 4, 5, 15, 16, 17]);
        for n in sizes {
            // The subgroup matrix legs (quick) keep two flag patterns and one and four arrays:
            // the lane logic is the same for every pattern and array count.
            let patterns = if n > 1 << 20 {
                1
            } else if common::quick() {
                2
            } else {
                4
            };
            for (what, flags) in flag_inputs(n, &mut rng).into_iter().take(patterns) {
                let (gpu, total) = scan.run_flags(&ctx, &flags).unwrap();
                let (cpu, cpu_total) = flag_scan_cpu(&flags);
                let diff = gpu.iter().zip(&cpu).position(|(g, c)| g != c);
                assert_eq!(diff, None, "{cfg:?} n={n} {what}: first difference");
                assert_eq!(total, cpu_total, "{cfg:?} n={n} {what}: total");
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn compaction_of_one_to_four_soa_arrays_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(4);
    for cfg in configs(&ctx) {
        let compact = Compact::new(&ctx, cfg).unwrap();
        let tile = compact.tile_elements();
        for n in common::edge_sizes(
            ctx.info().subgroup_size as usize,
            cfg.workgroup_size as usize,
            tile,
        ) {
            let arrays_n = if n > 1 << 20 { 2 } else { 4 };
            // The subgroup matrix legs (quick) keep two flag patterns and one and four arrays:
            // the lane logic is the same for every pattern and array count.
            let patterns = if n > 1 << 20 {
                1
            } else if common::quick() {
                2
            } else {
                4
            };
            for (what, flags) in flag_inputs(n, &mut rng).into_iter().take(patterns) {
                let data: Vec<Vec<u32>> = (0..arrays_n)
                    .map(|_| (0..n).map(|_| rng.next_u64() as u32).collect())
                    .collect();
                let counts: Vec<usize> = if common::quick() {
                    vec![1, arrays_n]
                } else {
                    (1..=arrays_n).collect()
                };
                for k in counts {
                    let arrays: Vec<&[u32]> = data[..k].iter().map(|v| v.as_slice()).collect();
                    let gpu = compact.run(&ctx, &flags, &arrays).unwrap();
                    assert!(
                        gpu == compact_cpu(&flags, &arrays),
                        "{cfg:?} n={n} {what} arrays={k}"
                    );
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

/// Compaction over a count that lives on the GPU (`record_counted`): only the first
/// `ceil(count · mul / div)` flags count, whatever the flags beyond say.
#[test]
fn counted_compaction_uses_the_gpu_count() {
    use vkrt::gpu::{Buffer, BufferArg, Recorder};
    use vkrt::prims::scan::GpuCount;
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(41);
    for cfg in configs(&ctx) {
        let compact = Compact::new(&ctx, cfg).unwrap();
        let tile = compact.tile_elements();
        let capacity = 3 * tile + 5;
        let flags: Vec<u8> = (0..capacity)
            .map(|_| (rng.next_u64() % 3 == 0) as u8)
            .collect();
        let data: Vec<u32> = (0..capacity as u32).collect();
        let flag_buf = Buffer::from_slice(&ctx, "flags", &flags).unwrap();
        let input = Buffer::from_slice(&ctx, "in", &data).unwrap();
        for live in [0usize, 1, 7, tile / 2 + 1, tile + 3, capacity / 2] {
            // counts[1] = live; n = 2 · live (as the renderer's two child slots per ray)
            let counts = Buffer::from_slice(&ctx, "counts", &[99u32, live as u32]).unwrap();
            let out = Buffer::<u32>::zeroed(&ctx, "out", capacity).unwrap();
            let scratch = compact.scratch(&ctx, capacity).unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            let count = GpuCount {
                counts: &counts,
                index: 1,
                mul: 2,
                div: 1,
            };
            let ins: [&dyn BufferArg; 1] = [&input];
            let outs: [&dyn BufferArg; 1] = [&out];
            compact.record_counted(&mut rec, &flag_buf, capacity, count, &ins, &outs, &scratch);
            rec.compute_to_transfer();
            rec.submit_and_wait().unwrap();
            let n = (2 * live).min(capacity);
            let want = compact_cpu(&flags[..n], &[&data[..n]]).remove(0);
            let kept = scratch.count().download().unwrap()[0] as usize;
            assert_eq!(kept, want.len(), "{cfg:?} live={live}");
            assert_eq!(
                &out.download().unwrap()[..kept],
                &want[..],
                "{cfg:?} live={live}"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn scan_works_in_place_and_past_every_level() {
    let Some(ctx) = common::context() else { return };
    // A tiny tile makes three levels of tile sums out of a modest n.
    let cfg = PrimConfig {
        workgroup_size: ctx.info().subgroup_size,
        items_per_invocation: 4,
    };
    let scan = Scan::new(&ctx, cfg, ScanInput::U32).unwrap();
    let tile = cfg.tile() as usize;
    let n = tile * tile * tile + 3;
    let input: Vec<u32> = (0..n as u32).map(|i| i % 13).collect();
    let buffer = vkrt::gpu::Buffer::from_slice(&ctx, "inplace", &input).unwrap();
    let scratch = scan.scratch(&ctx, n).unwrap();
    let mut rec = vkrt::gpu::Recorder::new(&ctx).unwrap();
    scan.record(&mut rec, &buffer, &buffer, n, ScanOp::Exclusive, &scratch);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    assert!(buffer.download().unwrap() == scan_cpu(&input, ScanOp::Exclusive).0);
    common::assert_silent(&ctx);
}

#[test]
fn contiguous_variant_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(5);
    for cfg in configs(&ctx) {
        let u32_scan =
            Scan::with_variant(&ctx, cfg, ScanInput::U32, ScanVariant::Contiguous).unwrap();
        let flag_scan =
            Scan::with_variant(&ctx, cfg, ScanInput::Flags, ScanVariant::Contiguous).unwrap();
        let sg = ctx.info().subgroup_size as usize;
        for n in common::edge_sizes(sg, cfg.workgroup_size as usize, 4 * cfg.tile() as usize) {
            let input: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
            let (gpu, total) = u32_scan.run_u32(&ctx, &input, ScanOp::Exclusive).unwrap();
            assert!(
                (gpu, total) == scan_cpu(&input, ScanOp::Exclusive),
                "{cfg:?} n={n} u32"
            );
            let flags: Vec<u8> = (0..n).map(|_| (rng.next_u64() & 1) as u8).collect();
            assert!(
                flag_scan.run_flags(&ctx, &flags).unwrap() == flag_scan_cpu(&flags),
                "{cfg:?} n={n} flags"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn counted_scans_read_their_length_from_the_gpu() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(6);
    for cfg in configs(&ctx) {
        let scan = Scan::new(&ctx, cfg, ScanInput::U32).unwrap();
        let flag_scan = Scan::new(&ctx, cfg, ScanInput::Flags).unwrap();
        // Several tiles, so the tile sums are scanned by a second level.
        let capacity = 5 * 4 * cfg.tile() as usize + 5;
        let input: Vec<u32> = (0..capacity).map(|_| (rng.next_u64() % 5) as u32).collect();
        let flags: Vec<u8> = (0..capacity).map(|_| (rng.next_u64() & 1) as u8).collect();
        let data = vkrt::gpu::Buffer::from_slice(&ctx, "counted.in", &input).unwrap();
        let flag_data = vkrt::gpu::Buffer::from_slice(&ctx, "counted.flags", &flags).unwrap();
        let out = vkrt::gpu::Buffer::<u32>::zeroed(&ctx, "counted.out", capacity).unwrap();
        let scratch = scan.scratch(&ctx, capacity).unwrap();
        let flag_scratch = flag_scan.scratch(&ctx, capacity).unwrap();
        // The real count is stored / 2 * 2 (mul 2): 0, 1, tile-ish and the capacity itself.
        for stored in [0u32, 1, 7, cfg.tile() / 2 + 1, (capacity / 2) as u32] {
            let n = (2 * stored as usize).min(capacity);
            let counts =
                vkrt::gpu::Buffer::from_slice(&ctx, "counted.counts", &[99, stored]).unwrap();
            let count = vkrt::prims::scan::GpuCount {
                counts: &counts,
                index: 1,
                mul: 2,
                div: 1,
            };
            let mut rec = vkrt::gpu::Recorder::new(&ctx).unwrap();
            scan.record_counted(
                &mut rec,
                &data,
                &out,
                capacity,
                count,
                ScanOp::Exclusive,
                &scratch,
            );
            rec.compute_to_compute();
            rec.compute_to_transfer();
            rec.submit_and_wait().unwrap();
            let (cpu, total) = scan_cpu(&input[..n], ScanOp::Exclusive);
            assert!(
                out.download().unwrap()[..n] == cpu[..],
                "{cfg:?} counted n={n}"
            );
            assert_eq!(
                scratch.total.download().unwrap()[0],
                total,
                "{cfg:?} counted n={n} total"
            );
            let mut rec = vkrt::gpu::Recorder::new(&ctx).unwrap();
            flag_scan.record_counted(
                &mut rec,
                &flag_data,
                &out,
                capacity,
                count,
                ScanOp::Exclusive,
                &flag_scratch,
            );
            rec.compute_to_transfer();
            rec.submit_and_wait().unwrap();
            let (cpu, total) = flag_scan_cpu(&flags[..n]);
            assert!(
                out.download().unwrap()[..n] == cpu[..],
                "{cfg:?} counted flags n={n}"
            );
            assert_eq!(
                flag_scratch.total.download().unwrap()[0],
                total,
                "{cfg:?} counted flags n={n} total"
            );
        }
    }
    common::assert_silent(&ctx);
}

/// The chained scan's look-back, made to reduce every predecessor tile from the input
/// (timing alone reaches that path only sometimes), still equals the CPU twin; and the
/// device here does run the chained path (lavapipe has 64-bit buffer atomics).
/// `scan` of `n` random u32 words (inclusive and exclusive) or random 0/1 flags against its
/// CPU twin.
fn check_random(
    ctx: &Context,
    scan: &Scan,
    kind: ScanInput,
    n: usize,
    rng: &mut common::Rng,
    case: &str,
) {
    if kind == ScanInput::U32 {
        let input: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
        for op in [ScanOp::Inclusive, ScanOp::Exclusive] {
            let got = scan.run_u32(ctx, &input, op).unwrap();
            assert!(got == scan_cpu(&input, op), "{case} u32 {op:?}");
        }
    } else {
        let flags: Vec<u8> = (0..n).map(|_| (rng.next_u64() & 1) as u8).collect();
        let got = scan.run_flags(ctx, &flags).unwrap();
        assert!(got == flag_scan_cpu(&flags), "{case} flags");
    }
}

/// Scans from `Scan::large_tiles` on take longer tiles (8x for u32, 4x for flags at the
/// default shape): their boundaries, and the switch itself, against the CPU twin.
#[test]
fn chained_scan_large_tiles_equal_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(7);
    let cfg = PrimConfig::default_for(&ctx);
    for input_kind in [ScanInput::U32, ScanInput::Flags] {
        let scan = Scan::new(&ctx, cfg, input_kind).unwrap();
        let (large_tile, large_from) = scan.large_tiles().expect("chained scan");
        assert!(large_tile > scan.tile_elements(), "large tiles are larger");
        for n in [
            large_from - 1,
            large_from,
            large_from + 1,
            large_from + large_tile - 1,
            large_from + large_tile + 1,
        ] {
            check_random(&ctx, &scan, input_kind, n, &mut rng, &format!("n={n}"));
        }
    }
    common::assert_silent(&ctx);
}

/// The form of the chained scan's granule loops the device does not take (rolled, or
/// unrolled with the granules in registers: `DeviceInfo::rolled_scan_tiles`) equals the CPU
/// twin too, at small tiles: the other tests run the device's own form. (Its large tiles are
/// what the choice avoids: unrolled, a 25 s compile on Mesa 25.0's lavapipe.)
#[test]
fn the_other_form_of_the_chained_scan_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(8);
    let rolled = !ctx.info().rolled_scan_tiles;
    for cfg in configs(&ctx) {
        for kind in [ScanInput::U32, ScanInput::Flags] {
            let scan = Scan::with_tile_loops(&ctx, cfg, kind, rolled, false)
                .unwrap()
                .expect("chained scan");
            let tile = scan.tile_elements();
            for n in [1, tile - 1, tile, tile + 1, 3 * tile + 7] {
                let case = format!("{cfg:?} rolled {rolled} n={n}");
                check_random(&ctx, &scan, kind, n, &mut rng, &case);
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn chained_scan_fallback_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    assert!(
        Scan::new(&ctx, PrimConfig::default_for(&ctx), ScanInput::U32)
            .unwrap()
            .is_chained(),
        "lavapipe should take the single-pass path"
    );
    let mut rng = common::Rng(6);
    for (cfg, large_tiles) in configs(&ctx)
        .into_iter()
        .flat_map(|c| [(c, false), (c, true)])
    {
        let forced = |input| {
            Scan::with_forced_fallback(&ctx, cfg, input, large_tiles)
                .unwrap()
                .expect("chained scan")
        };
        for kind in [ScanInput::U32, ScanInput::Flags] {
            let scan = forced(kind);
            let tile = if large_tiles {
                scan.large_tiles().expect("chained scan").0
            } else {
                scan.tile_elements()
            };
            // O(tiles²) reads: a few tiles are enough to cross every boundary.
            for n in [tile - 1, tile, tile + 1, 3 * tile + 7, 9 * tile + 1] {
                let case = format!("{cfg:?} large tiles {large_tiles} n={n}");
                check_random(&ctx, &scan, kind, n, &mut rng, &case);
            }
        }
    }
    common::assert_silent(&ctx);
}
