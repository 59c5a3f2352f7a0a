//! The key-value radix sort against its CPU twin and against `slice::sort_by_key` (stable,
//! an independent oracle), bit for bit, at every edge size and on inputs that test
//! stability (all-equal keys, few distinct keys), with a one-subgroup workgroup and a
//! several-subgroup one, every digit width, and f32 keys with signed zeros, denormals and
//! infinities — under validation and synchronization validation.

mod common;

use vkrt::gpu::{Buffer, Context, Recorder};
use vkrt::prims::radix_sort::{
    radix_sort_cpu, radix_sort_f32_cpu, radix_sort_passes_cpu, RadixSort, Ranking, SortGate,
    BITS_RANGE, DEFAULT_BITS_PER_PASS,
};
use vkrt::prims::PrimConfig;

fn configs(ctx: &Context) -> [PrimConfig; 2] {
    [
        PrimConfig::single_subgroup(ctx),
        PrimConfig::default_for(ctx),
    ]
}

/// The sizes a sort is tested at: the common edge sizes for its tile, and around its
/// scatter workgroup.
fn sizes(ctx: &Context, sort: &RadixSort) -> Vec<usize> {
    let sg = ctx.info().subgroup_size as usize;
    let mut sizes = common::edge_sizes(sg, sort.config().workgroup_size as usize, sort.tile());
    let wg = sort.scatter_workgroup_size() as usize;
    sizes.extend([wg - 1, wg, wg + 1, 2 * sort.tile() + 5]);
    sizes.sort_unstable();
    sizes.dedup();
    sizes
}

/// Keys of one size: full-range random, few distinct, all equal, sorted, reversed, small.
fn key_inputs(n: usize, rng: &mut common::Rng) -> Vec<(&'static str, Vec<u32>)> {
    vec![
        ("random", (0..n).map(|_| rng.next_u64() as u32).collect()),
        (
            "few-distinct",
            (0..n)
                .map(|_| [7, 0x8000_0000, 0xffff_ffff, 1 << 16][(rng.next_u64() % 4) as usize])
                .collect(),
        ),
        ("all-equal", vec![0x1234_5678; n]),
        ("sorted", (0..n as u32).collect()),
        ("reverse", (0..n as u32).rev().collect()),
        (
            "small",
            (0..n).map(|_| (rng.next_u64() % 1000) as u32).collect(),
        ),
    ]
}

/// The stable oracle: `sort_by_key` of (key, value) pairs.
fn oracle(keys: &[u32], values: &[u32], key_bits: u32) -> (Vec<u32>, Vec<u32>) {
    let mask = if key_bits == 32 {
        u32::MAX
    } else {
        (1u32 << key_bits) - 1
    };
    let mut pairs: Vec<(u32, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    pairs.sort_by_key(|p| p.0 & mask);
    pairs.into_iter().unzip()
}

fn first_difference<T: PartialEq>(a: &[T], b: &[T]) -> Option<usize> {
    if a.len() != b.len() {
        return Some(a.len().min(b.len()));
    }
    a.iter().zip(b).position(|(x, y)| x != y)
}

fn rankings() -> [Ranking; 3] {
    Ranking::ALL
}

/// The sort with `ranking`, or None when its shared memory does not fit this device's
/// subgroup size (`RadixSort::new` then picks another ranking) or its digits are wider
/// than the ranking takes.
fn sort_with(ctx: &Context, cfg: PrimConfig, bits: u32, ranking: Ranking) -> Option<RadixSort> {
    if bits > 8 && ranking != Ranking::Runs {
        return None; // the shared-memory rankings take up to 8 bits
    }
    match RadixSort::with_ranking(ctx, cfg, bits, ranking) {
        Ok(sort) => Some(sort),
        Err(e) => {
            eprintln!("skipped {ranking:?} ranking of {bits}-bit digits with {cfg:?}: {e}");
            None
        }
    }
}

/// Sorts with `record` (by `key_bits`) and checks the result against the CPU twin of the
/// same digit width and against `sort_by_key` on the masked keys.
fn check_record(
    ctx: &Context,
    sort: &RadixSort,
    keys: &[u32],
    values: &[u32],
    key_bits: u32,
    case: &str,
) {
    let n = keys.len();
    let k = Buffer::from_slice(ctx, "keys", keys).unwrap();
    let v = Buffer::from_slice(ctx, "values", values).unwrap();
    let scratch = sort.scratch(ctx, n).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    sort.record(&mut rec, &k, &v, n, key_bits, &scratch);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    let (gk, gv) = (k.download().unwrap(), v.download().unwrap());
    let cpu = radix_sort_passes_cpu(keys, values, key_bits, sort.bits_per_pass());
    assert_eq!(
        first_difference(&gk, &cpu.0),
        None,
        "{case}: keys vs CPU twin"
    );
    assert_eq!(
        first_difference(&gv, &cpu.1),
        None,
        "{case}: values vs CPU twin"
    );
    assert!(
        cpu == oracle(keys, values, key_bits),
        "{case}: CPU twin vs sort_by_key"
    );
}

#[test]
fn u32_sort_equals_cpu_twin_and_stable_sort_at_every_edge_size() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(61);
    for cfg in configs(&ctx) {
        let default = RadixSort::new(&ctx, cfg, DEFAULT_BITS_PER_PASS).unwrap();
        for ranking in rankings() {
            let Some(sort) = sort_with(&ctx, cfg, DEFAULT_BITS_PER_PASS, ranking) else {
                continue;
            };
            for n in sizes(&ctx, &sort) {
                let big = n > 1 << 20;
                if big && ranking != default.ranking() {
                    continue; // the largest sizes once per configuration, with the default ranking
                }
                // Values are the input positions: a stable sort keeps them increasing among equal keys.
                let values: Vec<u32> = (0..n as u32).collect();
                for (what, keys) in
                    key_inputs(n, &mut rng)
                        .into_iter()
                        .take(if big { 2 } else { 6 })
                {
                    let case = format!("{cfg:?} {ranking:?} n={n} {what}");
                    let (gk, gv) = sort.sort_u32(&ctx, &keys, &values).unwrap();
                    let (ck, cv) = radix_sort_cpu(&keys, &values);
                    assert_eq!(first_difference(&gk, &ck), None, "{case}: keys vs CPU twin");
                    assert_eq!(
                        first_difference(&gv, &cv),
                        None,
                        "{case}: values vs CPU twin"
                    );
                    let (ok, ov) = oracle(&keys, &values, 32);
                    assert_eq!(
                        first_difference(&ck, &ok),
                        None,
                        "{case}: CPU twin keys vs sort_by_key"
                    );
                    assert_eq!(
                        first_difference(&cv, &ov),
                        None,
                        "{case}: CPU twin values vs sort_by_key"
                    );
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn every_digit_width_ranking_and_key_width_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(62);
    for cfg in configs(&ctx) {
        for ranking in rankings() {
            // The matrix legs keep one odd and one even pass count: digit width does not
            // change how lanes cooperate.
            let widths: Vec<u32> = if common::quick() {
                vec![3, 8, 11]
            } else {
                BITS_RANGE.collect()
            };
            for bits in widths {
                let Some(sort) = sort_with(&ctx, cfg, bits, ranking) else {
                    continue;
                };
                let tile = sort.tile();
                for n in [0, 1, 33, tile + 1, 2 * tile + 7] {
                    let values: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
                    let keys: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
                    // Odd and even pass counts (the odd ones end with the copy back), and key
                    // bits above `key_bits` that must be ignored.
                    for key_bits in [32, 17] {
                        let case =
                            format!("{cfg:?} {ranking:?} bits={bits} key_bits={key_bits} n={n}");
                        check_record(&ctx, &sort, &keys, &values, key_bits, &case);
                    }
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn sorting_by_no_bits_or_one_bit_is_stable() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(64);
    let cfg = PrimConfig::default_for(&ctx);
    for ranking in rankings() {
        let Some(sort) = sort_with(&ctx, cfg, DEFAULT_BITS_PER_PASS, ranking) else {
            continue;
        };
        let n = sort.tile() * 3 + 11;
        let keys: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
        let values: Vec<u32> = (0..n as u32).collect();
        for key_bits in [0, 1, 2, 9] {
            check_record(
                &ctx,
                &sort,
                &keys,
                &values,
                key_bits,
                &format!("{ranking:?} key_bits={key_bits}"),
            );
        }
    }
    common::assert_silent(&ctx);
}

/// f32 keys: random magnitudes from denormal to huge, both zeros, both infinities.
fn float_keys(n: usize, rng: &mut common::Rng) -> Vec<f32> {
    let special = [
        0.0,
        -0.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MIN_POSITIVE,
        -f32::MIN_POSITIVE,
        1e-45,
        -1e-45,
        f32::MAX,
        f32::MIN,
        1.0,
        -1.0,
    ];
    (0..n)
        .map(|_| match rng.next_u64() % 4 {
            0 => special[(rng.next_u64() % special.len() as u64) as usize],
            1 => rng.next_f32() * 1e-40, // denormals
            2 => rng.next_f32() * 10f32.powi((rng.next_u64() % 77) as i32 - 38),
            _ => {
                // Any non-NaN bit pattern.
                let bits = rng.next_u64() as u32;
                let x = f32::from_bits(bits);
                if x.is_nan() {
                    f32::from_bits(bits & 0xff7f_ffff)
                } else {
                    x
                }
            }
        })
        .collect()
}

#[test]
fn f32_sort_orders_signed_zeros_denormals_and_infinities() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(63);
    for (cfg, ranking) in configs(&ctx)
        .into_iter()
        .flat_map(|c| rankings().map(|r| (c, r)))
    {
        let Some(sort) = sort_with(&ctx, cfg, DEFAULT_BITS_PER_PASS, ranking) else {
            continue;
        };
        let tile = sort.tile();
        for n in [0, 1, 2, 12, tile - 1, tile + 1, 100_003] {
            let keys = float_keys(n, &mut rng);
            let values: Vec<u32> = (0..n as u32).collect();
            let (gk, gv) = sort.sort_f32(&ctx, &keys, &values).unwrap();
            let (ck, cv) = radix_sort_f32_cpu(&keys, &values);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                first_difference(&bits(&gk), &bits(&ck)),
                None,
                "{cfg:?} {ranking:?} n={n}: keys vs CPU twin"
            );
            assert_eq!(
                first_difference(&gv, &cv),
                None,
                "{cfg:?} {ranking:?} n={n}: values vs CPU twin"
            );
            // The oracle: a stable sort by total_cmp, which orders -0.0 before +0.0 too.
            let mut pairs: Vec<(f32, u32)> =
                keys.iter().copied().zip(values.iter().copied()).collect();
            pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (ok, ov): (Vec<f32>, Vec<u32>) = pairs.into_iter().unzip();
            assert_eq!(
                first_difference(&bits(&ck), &bits(&ok)),
                None,
                "{cfg:?} n={n}: CPU twin vs total_cmp"
            );
            assert_eq!(
                first_difference(&cv, &ov),
                None,
                "{cfg:?} n={n}: CPU twin values vs total_cmp"
            );
            assert!(
                gk.windows(2).all(|w| w[0] <= w[1]),
                "{cfg:?} n={n}: not in float order"
            );
        }
    }
    // Signed zeros: every -0.0 before every +0.0, each side in input order.
    let sort = RadixSort::new(&ctx, PrimConfig::default_for(&ctx), DEFAULT_BITS_PER_PASS).unwrap();
    let keys = [
        0.0,
        -0.0,
        0.0,
        -0.0,
        f32::INFINITY,
        -1e-45,
        f32::NEG_INFINITY,
    ];
    let (gk, gv) = sort.sort_f32(&ctx, &keys, &[0, 1, 2, 3, 4, 5, 6]).unwrap();
    assert_eq!(gv, [6, 5, 1, 3, 0, 2, 4]);
    assert_eq!(
        gk.iter().map(|x| x.to_bits()).collect::<Vec<_>>()[2..6],
        [0x8000_0000, 0x8000_0000, 0, 0]
    );
    common::assert_silent(&ctx);
}

#[test]
fn nan_keys_are_an_error() {
    let Some(ctx) = common::context() else { return };
    let sort = RadixSort::new(&ctx, PrimConfig::default_for(&ctx), DEFAULT_BITS_PER_PASS).unwrap();
    let err = sort
        .sort_f32(&ctx, &[1.0, f32::NAN, 0.0], &[0, 1, 2])
        .unwrap_err();
    assert!(err.to_string().contains("key 1 is NaN"), "{err}");
    common::assert_silent(&ctx);
}

#[test]
fn unsupported_digit_widths_are_an_error() {
    let Some(ctx) = common::context() else { return };
    let cfg = PrimConfig::default_for(&ctx);
    for bits in [0, 13, 32] {
        assert!(RadixSort::new(&ctx, cfg, bits).is_err(), "{bits} bits");
    }
    // Wider than 8 bits only with the device-memory counters of `Runs`.
    for ranking in [Ranking::Counters, Ranking::Match] {
        let err = RadixSort::with_ranking(&ctx, cfg, 9, ranking).err();
        let err = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(
            err.contains("takes 1 to 8"),
            "{ranking:?} with 9 bits: {err}"
        );
    }
    assert!(RadixSort::with_ranking(&ctx, cfg, 12, Ranking::Runs).is_ok());
    common::assert_silent(&ctx);
}

#[test]
fn a_gated_sort_sorts_when_open_and_leaves_its_input_when_shut() {
    // The gate's words as a kernel writes them: the tile grid, the copy grid, then the count
    // table's length (open), or zeros (shut). Odd key widths end with the copy, so both
    // indirect grids and the counted scans are exercised.
    let Some(ctx) = common::context() else { return };
    // The gate changes how the passes are dispatched, not how they rank: the device's own
    // ranking stands for all.
    let mut rng = common::Rng(41);
    {
        let sort =
            RadixSort::new(&ctx, PrimConfig::default_for(&ctx), DEFAULT_BITS_PER_PASS).unwrap();
        let ranking = sort.ranking();
        for n in sizes(&ctx, &sort) {
            let keys: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
            let values: Vec<u32> = (0..n as u32).collect();
            for (key_bits, open) in [(32, true), (17, true), (17, false)] {
                let case = format!("{ranking:?}, n = {n}, {key_bits} bits, open {open}");
                let k = Buffer::from_slice(&ctx, "keys", &keys).unwrap();
                let v = Buffer::from_slice(&ctx, "values", &values).unwrap();
                let scratch = sort.scratch(&ctx, n.max(1)).unwrap();
                let mut rec = Recorder::new(&ctx).unwrap();
                let mut words = vec![0u32; 7];
                if open {
                    let [tiles, copy] = sort.grids(&rec, n);
                    words[..3].copy_from_slice(&tiles);
                    words[3..6].copy_from_slice(&copy);
                    words[6] = sort.table_len(n) as u32;
                }
                let args = Buffer::from_slice(&ctx, "gate", &words).unwrap();
                let gate = SortGate {
                    args: &args,
                    tiles: 0,
                    copy: 12,
                    table: 6,
                };
                sort.record_gated(&mut rec, &k, &v, n, key_bits, &scratch, &gate);
                rec.compute_to_transfer();
                rec.submit_and_wait().unwrap();
                let (gk, gv) = (k.download().unwrap(), v.download().unwrap());
                let want = if open {
                    oracle(&keys, &values, key_bits)
                } else {
                    (keys.clone(), values.clone())
                };
                assert_eq!(first_difference(&gk, &want.0), None, "{case}: keys");
                assert_eq!(first_difference(&gv, &want.1), None, "{case}: values");
            }
        }
    }
    common::assert_silent(&ctx);
}
