//! Segmented argmin against its CPU twin, bit for bit, in every mode (workgroup per
//! segment, device-wide tiles, hybrid at several thresholds, which packs the levels of many
//! segments) on many segment shapes, with a workgroup of one subgroup and with several, with
//! the shuffle and the shared-memory workgroup reduction, under synchronization validation.

mod common;

use common::Rng;
use vkrt::gpu::{Buffer, Context, Recorder};
use vkrt::prims::reduce::CostIndex;
use vkrt::prims::segmented::{self, SegmentedArgmin, SegmentedMode};
use vkrt::prims::PrimConfig;

fn configs(ctx: &Context) -> [(&'static str, PrimConfig); 2] {
    [
        ("single_subgroup", PrimConfig::single_subgroup(ctx)),
        ("default", PrimConfig::default_for(ctx)),
    ]
}

/// Every mode, plus hybrids at other thresholds (1: only over-capacity segments are long).
fn modes(ctx: &Context) -> Vec<SegmentedMode> {
    vec![
        SegmentedMode::WorkgroupPerSegment,
        SegmentedMode::DeviceWide,
        SegmentedMode::hybrid_for(ctx),
        SegmentedMode::Hybrid { threshold: 1 },
        SegmentedMode::Hybrid { threshold: 3 },
        SegmentedMode::Hybrid { threshold: 1000 },
    ]
}

/// Costs with many ties (few distinct values, both zeros): the tie-break by global index
/// decides most segments.
fn tie_costs(n: usize, rng: &mut Rng) -> Vec<f32> {
    (0..n)
        .map(|_| match rng.next_u64() % 8 {
            0 => -0.0,
            1 => 0.0,
            k => k as f32 * 0.25,
        })
        .collect()
}

fn random_costs(n: usize, rng: &mut Rng) -> Vec<f32> {
    (0..n).map(|_| rng.next_f32() * 1e6).collect()
}

fn offsets_from_lengths(start: u32, lengths: &[u32]) -> Vec<u32> {
    let mut offsets = vec![start];
    for &l in lengths {
        offsets.push(offsets.last().unwrap() + l);
    }
    offsets
}

/// Runs every mode of `seg` in one submission (the count lives on the GPU; `count` may be
/// below the capacity `offsets.len() - 1`, or above it to test the clamp) and compares each
/// with the twin.
fn check(
    ctx: &Context,
    seg: &SegmentedArgmin,
    costs: &[f32],
    offsets: &[u32],
    count: u32,
    what: &str,
) {
    let max_segments = offsets.len() as u32 - 1;
    let costs_buf = Buffer::from_slice(ctx, "test.costs", costs).unwrap();
    let offsets_buf = Buffer::from_slice(ctx, "test.offsets", offsets).unwrap();
    let count_buf = Buffer::from_slice(ctx, "test.count", &[count]).unwrap();
    let scratch = Buffer::<u32>::new(
        ctx,
        "test.scratch",
        seg.scratch_len(costs.len(), max_segments as usize),
    )
    .unwrap();
    let modes = modes(ctx);
    let outs: Vec<Buffer<CostIndex>> = modes
        .iter()
        .map(|_| Buffer::new(ctx, "test.out", max_segments as usize).unwrap())
        .collect();
    let mut rec = Recorder::new(ctx).unwrap();
    for (mode, out) in modes.iter().zip(&outs) {
        seg.record(
            &mut rec,
            *mode,
            &costs_buf,
            &offsets_buf,
            &count_buf,
            max_segments,
            &scratch,
            out,
        );
        // The next mode reuses `scratch` (and its indirect arguments).
        rec.compute_to_indirect();
    }
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    let effective = count.min(max_segments);
    let want = segmented::segmented_argmin_cpu(costs, offsets, effective);
    for (mode, out) in modes.iter().zip(&outs) {
        let got = out.download().unwrap();
        for s in 0..effective as usize {
            assert_eq!(
                got[s].bits(),
                want[s].bits(),
                "{what}, {mode:?}, {:?}: segment {s} = [{}, {}) of {}: GPU {:?}, CPU {:?}",
                seg.config(),
                offsets[s],
                offsets[s + 1],
                effective,
                got[s],
                want[s]
            );
        }
    }
}

/// [`check`] over every segment of `offsets` (the count is the capacity).
fn check_every_segment(
    ctx: &Context,
    seg: &SegmentedArgmin,
    costs: &[f32],
    offsets: &[u32],
    what: &str,
) {
    check(ctx, seg, costs, offsets, offsets.len() as u32 - 1, what);
}

/// The shapes every configuration is tested on: (name, offsets).
fn shapes(cfg: PrimConfig, packed_cut: u32, n_big: u32, rng: &mut Rng) -> Vec<(String, Vec<u32>)> {
    let tile = cfg.tile();
    let threshold = 4 * tile;
    let mut shapes = vec![
        ("one empty".to_string(), vec![0, 0]),
        ("all empty".to_string(), vec![0; 1001]),
        ("one element".to_string(), vec![0, 1]),
        ("one huge".to_string(), vec![0, n_big]),
        (
            "one huge after unsegmented elements".to_string(),
            vec![7, n_big],
        ),
    ];
    // 1 .. 10^5 tiny segments (0 to 3 elements).
    for count in [1usize, 2, 3, 100, 100_000] {
        let lengths: Vec<u32> = (0..count).map(|_| (rng.next_u64() % 4) as u32).collect();
        shapes.push((format!("{count} tiny"), offsets_from_lengths(0, &lengths)));
    }
    // Lengths straddling one and several tiles, in one array.
    let mut lengths = Vec::new();
    for l in [
        tile - 1,
        tile,
        tile + 1,
        2 * tile - 1,
        threshold - 1,
        threshold,
        threshold + 1,
    ] {
        lengths.extend([l, 0, 1, l]);
    }
    shapes.push(("straddling".to_string(), offsets_from_lengths(3, &lengths)));
    // Mixed, heavy-tailed: mostly small, some a few tiles, a few of several tiles.
    let lengths: Vec<u32> = (0..3000)
        .map(|_| match rng.next_u64() % 100 {
            0 => threshold + (rng.next_u64() % u64::from(threshold)) as u32,
            1..=10 => (rng.next_u64() % u64::from(4 * tile)) as u32,
            _ => (rng.next_u64() % 40) as u32,
        })
        .collect();
    shapes.push(("mixed".to_string(), offsets_from_lengths(0, &lengths)));
    // A level of many segments (the packed path's), mostly short, some around its cut:
    // each lane's own loop, the subgroup's loop and the tiles' slots.
    let mut lengths: Vec<u32> = (0..600).map(|_| (rng.next_u64() % 48) as u32).collect();
    for (at, l) in [
        (5, packed_cut - 1),
        (64, packed_cut),
        (65, packed_cut + tile + 1),
        (300, 1000),
        (301, 33),
        (599, 2 * packed_cut),
    ] {
        lengths[at] = l;
    }
    shapes.push((
        "packed level".to_string(),
        offsets_from_lengths(1, &lengths),
    ));
    // kd-tree levels: 2^k equal segments.
    for level in [1u32, 5, 10] {
        shapes.push((
            format!("level {level}"),
            segmented::level_offsets(n_big, level),
        ));
    }
    shapes
}

#[test]
fn every_mode_equals_the_twin_on_every_shape() {
    let Some(ctx) = common::context() else { return };
    let quick = std::env::var("VKRT_TEST_QUICK").is_ok_and(|v| v == "1");
    let n_big = if quick {
        (1 << 18) + 13
    } else {
        (1 << 20) + 13
    };
    for (name, cfg) in configs(&ctx) {
        let seg = SegmentedArgmin::new(&ctx, cfg).unwrap();
        let mut rng = Rng(5);
        for (shape, offsets) in shapes(cfg, seg.packed_cut(), n_big, &mut rng) {
            let n = *offsets.last().unwrap() as usize + (rng.next_u64() % 5) as usize;
            let costs = if shape.contains("tiny") || shape.contains("straddling") {
                tie_costs(n, &mut rng)
            } else {
                random_costs(n, &mut rng)
            };
            check_every_segment(&ctx, &seg, &costs, &offsets, &format!("{name}, {shape}"));
            let ties = tie_costs(n, &mut rng);
            let what = format!("{name}, {shape}, ties");
            check_every_segment(&ctx, &seg, &ties, &offsets, &what);
        }
    }
    common::assert_silent(&ctx);
}

/// The shared-memory workgroup reduction (the ablation benchmark's baseline) against the
/// same twin, on every shape at a smaller size.
#[test]
fn the_shared_memory_reduction_equals_the_twin() {
    use vkrt::prims::segmented::WorkgroupReduction;
    let Some(ctx) = common::context() else { return };
    // Workgroups of one subgroup and of several (the shared tree spans subgroups).
    for (name, cfg) in configs(&ctx) {
        let seg = SegmentedArgmin::with_reduction(
            &ctx,
            cfg,
            cfg.workgroup_size,
            WorkgroupReduction::SharedMemory,
        )
        .unwrap();
        let mut rng = Rng(6);
        // ("mixed" is tens of millions of elements and 10^5 segments of 256-wide workgroups
        // take 20 s here: the shuffle test covers those sizes; 10^5 segments run with the
        // single-subgroup workgroups.)
        for (shape, offsets) in shapes(cfg, seg.packed_cut(), 3 * cfg.tile() + 13, &mut rng)
            .into_iter()
            .filter(|(shape, _)| {
                shape != "mixed"
                    && shape != "packed level"
                    && (name == "single_subgroup" || shape != "100000 tiny")
            })
        {
            let n = *offsets.last().unwrap() as usize;
            let costs = tie_costs(n, &mut rng);
            let what = format!("shared memory, {name}, {shape}");
            check_every_segment(&ctx, &seg, &costs, &offsets, &what);
        }
    }
    common::assert_silent(&ctx);
}

/// llvmpipe silently ends a loop after 65,535 iterations (Mesa 22.3): one segment long
/// enough that a single-subgroup workgroup's lanes loop far more often than that, with the
/// minimum at the very end, must still be found (the kernels split long loops).
#[test]
fn a_segment_longer_than_llvmpipes_loop_limit() {
    let Some(ctx) = common::context() else { return };
    let cfg = PrimConfig::single_subgroup(&ctx);
    let seg = SegmentedArgmin::new(&ctx, cfg).unwrap();
    // 65,535 iterations of 4 elements for each of up to 32 lanes is 8.4M elements.
    let n = 9_000_000u32;
    let mut rng = Rng(77);
    let mut costs: Vec<f32> = (0..n).map(|_| 1.0 + rng.next_f32().abs()).collect();
    costs[n as usize - 3] = 0.5;
    check_every_segment(
        &ctx,
        &seg,
        &costs,
        &[0, n],
        "one segment past the loop limit",
    );
    common::assert_silent(&ctx);
}

#[test]
fn the_count_is_read_on_the_gpu_and_clamped_to_the_capacity() {
    let Some(ctx) = common::context() else { return };
    for (name, cfg) in configs(&ctx) {
        let seg = SegmentedArgmin::new(&ctx, cfg).unwrap();
        let mut rng = Rng(9);
        let lengths: Vec<u32> = (0..64)
            .map(|i| {
                if i % 9 == 0 {
                    3 * cfg.tile()
                } else {
                    (rng.next_u64() % 300) as u32
                }
            })
            .collect();
        let offsets = offsets_from_lengths(0, &lengths);
        let n = *offsets.last().unwrap() as usize;
        let costs = tie_costs(n, &mut rng);
        for count in [0, 1, 17, 63, 64, 65, 1000] {
            check(
                &ctx,
                &seg,
                &costs,
                &offsets,
                count,
                &format!("{name}, count {count}"),
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn the_convenience_call_and_empty_segments() {
    let Some(ctx) = common::context() else { return };
    let seg = SegmentedArgmin::new(&ctx, PrimConfig::default_for(&ctx)).unwrap();
    let costs = [3.0, 1.0, -0.0, 0.0, 2.0, 0.0];
    let offsets = [0, 2, 2, 6];
    for mode in modes(&ctx) {
        let got = seg.argmin(&ctx, mode, &costs, &offsets).unwrap();
        let bits: Vec<_> = got.iter().map(CostIndex::bits).collect();
        assert_eq!(
            bits,
            vec![
                (1.0f32.to_bits(), 1),
                CostIndex::NONE.bits(),
                ((-0.0f32).to_bits(), 2)
            ],
            "{mode:?}"
        );
    }
    assert!(seg
        .argmin(&ctx, SegmentedMode::hybrid_for(&ctx), &[], &[])
        .unwrap()
        .is_empty());
    common::assert_silent(&ctx);
}
