//! Reductions and argmin against their CPU twins, bit for bit, at every edge size and on
//! adversarial inputs (ties, ±0.0, denormals, huge and tiny magnitudes), with a workgroup of
//! one subgroup and with several, under validation with synchronization validation.

mod common;

use common::Rng;
use vkrt::gpu::{Buffer, Context, Recorder};
use vkrt::prims::reduce::{self, CostIndex, Reduce};
use vkrt::prims::PrimConfig;

fn configs(ctx: &Context) -> [(&'static str, PrimConfig); 2] {
    [
        ("single_subgroup", PrimConfig::single_subgroup(ctx)),
        ("default", PrimConfig::default_for(ctx)),
    ]
}

/// Input patterns; each gives f32 costs (NaN-free) and u32 values.
#[derive(Clone, Copy, Debug)]
enum Pattern {
    /// Magnitudes from 1e-38 to 1e30, both signs (sums stay finite).
    Random,
    AllEqual,
    Sorted,
    ReverseSorted,
    /// Only -0.0 and +0.0.
    SignedZeros,
    /// Subnormals of both signs, and zeros.
    Denormals,
    /// Few distinct values, so the minimum repeats (tie-break by index).
    Ties,
    /// Every cost +inf (the argmin is still index 0, not NONE).
    AllInfinite,
}

const ALL_PATTERNS: [Pattern; 8] = [
    Pattern::Random,
    Pattern::AllEqual,
    Pattern::Sorted,
    Pattern::ReverseSorted,
    Pattern::SignedZeros,
    Pattern::Denormals,
    Pattern::Ties,
    Pattern::AllInfinite,
];

fn make_f32(pattern: Pattern, n: usize, rng: &mut Rng) -> Vec<f32> {
    let random_wide = |rng: &mut Rng| {
        let exp = -38.0 + 68.0 * (rng.next_f32() * 0.5 + 0.5);
        rng.next_f32() * 10f32.powf(exp)
    };
    match pattern {
        Pattern::Random => (0..n).map(|_| random_wide(rng)).collect(),
        Pattern::AllEqual => vec![0.1; n],
        Pattern::Sorted | Pattern::ReverseSorted => {
            let mut v: Vec<f32> = (0..n).map(|_| rng.next_f32() * 1e3).collect();
            v.sort_by(f32::total_cmp);
            if matches!(pattern, Pattern::ReverseSorted) {
                v.reverse();
            }
            v
        }
        Pattern::SignedZeros => (0..n)
            .map(|_| if rng.next_u64() & 1 == 0 { 0.0 } else { -0.0 })
            .collect(),
        Pattern::Denormals => (0..n)
            .map(|_| {
                let r = rng.next_u64();
                let mantissa = (r >> 8) as u32 & 0x007f_ffff;
                let sign = (r as u32 & 1) << 31;
                if r & 0xf0 == 0 {
                    f32::from_bits(sign)
                } else {
                    f32::from_bits(sign | mantissa)
                }
            })
            .collect(),
        Pattern::Ties => (0..n).map(|_| (rng.next_u64() % 5) as f32 - 2.0).collect(),
        Pattern::AllInfinite => vec![f32::INFINITY; n],
    }
}

/// u32 inputs: the bits of the f32 pattern (wide values, the sum wraps), or all u32::MAX.
fn make_u32(costs: &[f32], pattern: Pattern) -> Vec<u32> {
    match pattern {
        Pattern::AllEqual => vec![u32::MAX; costs.len()],
        _ => costs.iter().map(|c| c.to_bits()).collect(),
    }
}

/// [`check_all`] on `n` elements of `pattern`, as f32 costs and as u32 values.
fn check_pattern(
    ctx: &Context,
    reduce: &Reduce,
    pattern: Pattern,
    n: usize,
    rng: &mut Rng,
    what: &str,
) {
    let costs = make_f32(pattern, n, rng);
    let values = make_u32(&costs, pattern);
    check_all(ctx, reduce, &costs, &values, what);
}

struct Outputs {
    sum_u32: Buffer<u32>,
    min_u32: Buffer<u32>,
    max_u32: Buffer<u32>,
    sum_f32: Buffer<f32>,
    min_f32: Buffer<f32>,
    max_f32: Buffer<f32>,
    argmin: Buffer<CostIndex>,
}

/// Runs every reduction on one upload and compares each with its twin.
fn check_all(ctx: &Context, reduce: &Reduce, costs: &[f32], values: &[u32], what: &str) {
    let n = costs.len();
    let cfg = reduce.config();
    let f = Buffer::from_slice(ctx, "test.costs", costs).unwrap();
    let u = Buffer::from_slice(ctx, "test.values", values).unwrap();
    let scratch = Buffer::<u32>::new(ctx, "test.scratch", reduce.scratch_len(n)).unwrap();
    let out = Outputs {
        sum_u32: Buffer::new(ctx, "test.sum_u32", 1).unwrap(),
        min_u32: Buffer::new(ctx, "test.min_u32", 1).unwrap(),
        max_u32: Buffer::new(ctx, "test.max_u32", 1).unwrap(),
        sum_f32: Buffer::new(ctx, "test.sum_f32", 1).unwrap(),
        min_f32: Buffer::new(ctx, "test.min_f32", 1).unwrap(),
        max_f32: Buffer::new(ctx, "test.max_f32", 1).unwrap(),
        argmin: Buffer::new(ctx, "test.argmin", 1).unwrap(),
    };
    let n32 = n as u32;
    let mut rec = Recorder::new(ctx).unwrap();
    // Every chain reuses `scratch`: order each after the previous one.
    reduce.record_sum_u32(&mut rec, &u, n32, &scratch, &out.sum_u32);
    rec.compute_to_compute();
    reduce.record_min_u32(&mut rec, &u, n32, &scratch, &out.min_u32);
    rec.compute_to_compute();
    reduce.record_max_u32(&mut rec, &u, n32, &scratch, &out.max_u32);
    rec.compute_to_compute();
    reduce.record_sum_f32(&mut rec, &f, n32, &scratch, &out.sum_f32);
    rec.compute_to_compute();
    reduce.record_min_f32(&mut rec, &f, n32, &scratch, &out.min_f32);
    rec.compute_to_compute();
    reduce.record_max_f32(&mut rec, &f, n32, &scratch, &out.max_f32);
    rec.compute_to_compute();
    reduce.record_argmin(&mut rec, &f, n32, &scratch, &out.argmin);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();

    let one = |b: &Buffer<u32>| b.download().unwrap()[0];
    let one_f = |b: &Buffer<f32>| b.download().unwrap()[0].to_bits();
    let ctx_msg = format!("{what}, n = {n}, {cfg:?}");
    assert_eq!(
        one(&out.sum_u32),
        reduce::sum_u32_cpu(values),
        "sum_u32: {ctx_msg}"
    );
    assert_eq!(
        one(&out.min_u32),
        reduce::min_u32_cpu(values),
        "min_u32: {ctx_msg}"
    );
    assert_eq!(
        one(&out.max_u32),
        reduce::max_u32_cpu(values),
        "max_u32: {ctx_msg}"
    );
    let (got, want) = (
        one_f(&out.sum_f32),
        reduce::sum_f32_cpu(costs, cfg).to_bits(),
    );
    // Without the DenormPreserve execution mode a device may flush subnormal operands and
    // results of an addition to zero (GPUs do; lavapipe does not): either answer is exact.
    let flushed: Vec<f32> = costs.iter().map(|&x| flush_subnormal(x)).collect();
    let want_flushed = flush_subnormal(reduce::sum_f32_cpu(&flushed, cfg)).to_bits();
    assert!(
        got == want || got == want_flushed,
        "sum_f32: {ctx_msg}: GPU {} ({got:#x}), CPU {} ({want:#x}, flushing {want_flushed:#x})",
        f32::from_bits(got),
        f32::from_bits(want)
    );
    assert_eq!(
        one_f(&out.min_f32),
        reduce::min_f32_cpu(costs).to_bits(),
        "min_f32: {ctx_msg}"
    );
    assert_eq!(
        one_f(&out.max_f32),
        reduce::max_f32_cpu(costs).to_bits(),
        "max_f32: {ctx_msg}"
    );
    let got = out.argmin.download().unwrap()[0];
    let (cost, index) = reduce::argmin_cpu(costs);
    // A flushing device compares subnormals as zeros: the argmin under those comparisons,
    // reporting the element's own bits.
    let (_, flushed_index) = reduce::argmin_cpu(&flushed);
    let flushed_answer = costs
        .get(flushed_index as usize)
        .map_or((cost.to_bits(), index), |c| (c.to_bits(), flushed_index));
    assert!(
        got.bits() == (cost.to_bits(), index) || got.bits() == flushed_answer,
        "argmin: {ctx_msg}: GPU {got:?}, CPU ({cost}, {index}), flushing {flushed_answer:?}"
    );
}

#[test]
fn every_reduction_equals_its_twin_at_every_edge_size() {
    let Some(ctx) = common::context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    for (name, cfg) in configs(&ctx) {
        let reduce = Reduce::new(&ctx, cfg).unwrap();
        let sizes = common::edge_sizes(sg, cfg.workgroup_size as usize, cfg.tile() as usize);
        let mut rng = Rng(11);
        for (size_index, n) in sizes.into_iter().enumerate() {
            // Three patterns per size, rotating so each meets every size class; the large
            // sizes get the two that stress the f32 sum's order and the argmin's tie-break.
            let patterns: Vec<Pattern> = if n > 1 << 16 {
                vec![Pattern::Random, Pattern::Ties]
            } else {
                (0..3)
                    .map(|k| ALL_PATTERNS[(3 * size_index + k) % ALL_PATTERNS.len()])
                    .collect()
            };
            for pattern in patterns {
                let what = format!("{name}, {pattern:?}");
                check_pattern(&ctx, &reduce, pattern, n, &mut rng, &what);
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn every_reduction_equals_its_twin_on_random_sizes_and_patterns() {
    let Some(ctx) = common::context() else { return };
    let mut rng = Rng(2024);
    for (name, cfg) in configs(&ctx) {
        let reduce = Reduce::new(&ctx, cfg).unwrap();
        for round in 0..24 {
            let n = (rng.next_u64() % 200_000) as usize;
            let pattern = ALL_PATTERNS[round % ALL_PATTERNS.len()];
            let what = format!("{name}, {pattern:?}, round {round}");
            check_pattern(&ctx, &reduce, pattern, n, &mut rng, &what);
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn empty_inputs_give_the_documented_identities() {
    let Some(ctx) = common::context() else { return };
    let reduce = Reduce::new(&ctx, PrimConfig::default_for(&ctx)).unwrap();
    assert_eq!(reduce.sum_u32(&ctx, &[]).unwrap(), 0);
    assert_eq!(reduce.min_u32(&ctx, &[]).unwrap(), u32::MAX);
    assert_eq!(reduce.max_u32(&ctx, &[]).unwrap(), 0);
    assert_eq!(
        reduce.sum_f32(&ctx, &[]).unwrap().to_bits(),
        0.0f32.to_bits()
    );
    assert_eq!(reduce.min_f32(&ctx, &[]).unwrap(), f32::INFINITY);
    assert_eq!(reduce.max_f32(&ctx, &[]).unwrap(), f32::NEG_INFINITY);
    let (cost, index) = reduce.argmin(&ctx, &[]).unwrap();
    assert_eq!((cost, index), (f32::INFINITY, u32::MAX));
    // The twins agree.
    assert_eq!(reduce::sum_f32_cpu(&[], reduce.config()).to_bits(), 0);
    assert_eq!(reduce::argmin_cpu(&[]), (f32::INFINITY, u32::MAX));
    common::assert_silent(&ctx);
}

#[test]
fn argmin_breaks_ties_by_the_lowest_index_and_treats_signed_zeros_as_equal() {
    let Some(ctx) = common::context() else { return };
    for (_, cfg) in configs(&ctx) {
        let reduce = Reduce::new(&ctx, cfg).unwrap();
        let n = 3 * cfg.tile() as usize + 5;
        // +0.0 at the lowest index, -0.0 later: +0.0's index wins, with its sign.
        let mut costs = vec![1.0f32; n];
        costs[n - 2] = -0.0;
        costs[cfg.tile() as usize + 1] = 0.0;
        costs[n - 1] = -0.0;
        let (cost, index) = reduce.argmin(&ctx, &costs).unwrap();
        assert_eq!((cost.to_bits(), index), (0.0f32.to_bits(), cfg.tile() + 1));
        // The minimum repeated in every tile: the first one wins.
        let costs: Vec<f32> = (0..n).map(|i| (i % 7) as f32).collect();
        assert_eq!(reduce.argmin(&ctx, &costs).unwrap(), (0.0, 0));
        // min/max f32 order -0.0 below +0.0.
        let zeros = [0.0f32, -0.0, 0.0];
        assert_eq!(
            reduce.min_f32(&ctx, &zeros).unwrap().to_bits(),
            (-0.0f32).to_bits()
        );
        assert_eq!(
            reduce
                .max_f32(&ctx, &[-0.0f32, 0.0, -0.0])
                .unwrap()
                .to_bits(),
            0
        );
    }
    common::assert_silent(&ctx);
}

#[test]
fn bad_configurations_are_errors() {
    let Some(ctx) = common::context() else { return };
    let good = PrimConfig::default_for(&ctx);
    for cfg in [
        PrimConfig {
            items_per_invocation: 6,
            ..good
        },
        PrimConfig {
            workgroup_size: 3 * ctx.info().subgroup_size,
            ..good
        },
        // Past llvmpipe's loop limit (see reduce::MAX_ITEMS_PER_INVOCATION).
        PrimConfig {
            items_per_invocation: 2 * reduce::MAX_ITEMS_PER_INVOCATION,
            workgroup_size: ctx.info().subgroup_size,
        },
    ] {
        assert!(Reduce::new(&ctx, cfg).is_err(), "{cfg:?} accepted");
    }
}

/// `x` with a subnormal flushed to a zero of its sign, as a flushing device reads it.
fn flush_subnormal(x: f32) -> f32 {
    if x != 0.0 && x.abs() < f32::MIN_POSITIVE {
        f32::from_bits(x.to_bits() & 0x8000_0000)
    } else {
        x
    }
}
