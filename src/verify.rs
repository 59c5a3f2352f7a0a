//! `vkrt verify`: does vkrt compute correctly on this device? The conformance checks, run on
//! whatever device the context holds (Embree ships `verify` for the same question):
//!
//! - **rounding**: the walks' correctly rounded division and square root against the CPU's;
//! - **limits**: the loop budget the device is said to have (which sizes the walks' step
//!   cap) against what a long loop really runs;
//! - **primitives**: scan, reductions and radix sort against their CPU twins at the sizes
//!   that hit every edge (0, 1, subgroup ± 1, workgroup ± 1, tile ± 1, several tiles, large);
//! - **builders**: the GPU kd-tree, LBVH and PLOC against their CPU twins, bit for bit, and
//!   validated;
//! - **walks**: every structure and walk, both ray/triangle tests, closest and any hit,
//!   against brute force over every primitive;
//! - **instances**: `accel.instance_boxes` against its CPU twin bit for bit at the edge
//!   sizes (invalid instances among them), and the two-level walk over every kind of
//!   bottom level against its CPU twin (brute force in each bottom level), both tests,
//!   closest and any hit;
//! - **hard cases**: the robustness suite (watertightness, self-intersection, rays in split
//!   planes, degenerate geometry, builder stress, bad rays) on every vkrt structure, which
//!   must have no failure; the driver's own structure is reported, not required (Vulkan
//!   promises no watertightness);
//! - **validation**: with the validation layer on, it must stay silent.
//!
//! A check that errors is a failed check; the others still run. The integration test
//! `cli/tests/verify.rs` runs the same checks.

use std::collections::BTreeMap;
use std::time::Instant;

use glam::{Vec3, Vec4};
use serde::Serialize;

use crate::accel::bvh;
use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::host::HostStructure;
use crate::accel::primitives::TraceGeometry;
use crate::accel::walk::Traversal;
use crate::gpu::{kernels, Buffer, Context, Recorder, Result, Spec};
use crate::prims::radix_sort::{self, RadixSort, DEFAULT_BITS_PER_PASS};
use crate::prims::reduce::{self, Reduce};
use crate::prims::scan::{self, Scan, ScanInput, ScanOp};
use crate::prims::PrimConfig;
use crate::scene::gen::{self, Rng};
use crate::trace::gpu::Tracer;
use crate::trace::robust::{self, SuiteSize};
use crate::trace::{cpu, Hit, Intersector, Query, Ray, TraceOptions};

/// How much to check.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options {
    /// Fewer sizes and rays (no sizes past 2^16, the smallest hard-case suite): about a
    /// third of the default's time.
    pub quick: bool,
}

/// One check's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    /// The group the check belongs to (`rounding`, `walks`, `hard cases`, ...).
    pub group: &'static str,
    /// What was checked, with its sizes or structure.
    pub name: String,
    /// Whether it passed (a check that could not run failed).
    pub passed: bool,
    /// False for what is reported but not promised (the driver's hard cases).
    pub required: bool,
    /// What went wrong (the first difference), or what was measured.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub detail: String,
}

/// A group's checks in `Report::groups`.
#[derive(Clone, Debug, Default, Serialize)]
pub struct GroupSummary {
    /// Checks run in the group.
    pub checks: usize,
    /// Required checks that failed.
    pub failed: usize,
    /// Each failed check: `name: detail`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub failures: Vec<String>,
}

/// Every check of a run; `vkrt verify --json` prints it (without `results`).
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The device name the driver reports.
    pub device: String,
    /// The driver's name and info string.
    pub driver: String,
    /// Checks run.
    pub checks: usize,
    /// Failed required checks: non-zero is a device vkrt cannot be trusted on.
    pub failed: usize,
    /// Each group's summary, by group name.
    pub groups: BTreeMap<&'static str, GroupSummary>,
    /// Wall seconds of the whole run.
    pub seconds: f64,
    /// Every check in the order it ran.
    #[serde(skip)]
    pub results: Vec<Check>,
}

/// Sizes that hit every edge of a kernel with these `subgroup`, `workgroup` and `tile`
/// sizes: 0, 1, each ± 1, several tiles, and with `large` two past every scan level.
pub fn edge_sizes(subgroup: usize, workgroup: usize, tile: usize, large: bool) -> Vec<usize> {
    let mut sizes = vec![
        0,
        1,
        subgroup - 1,
        subgroup,
        subgroup + 1,
        workgroup - 1,
        workgroup,
        workgroup + 1,
        tile - 1,
        tile,
        tile + 1,
        4 * tile + 3,
    ];
    if large {
        sizes.extend([(1 << 20) + 13, (1 << 24) + 3]);
    }
    sizes.sort_unstable();
    sizes.dedup();
    sizes
}

/// Runs every check on `ctx`'s device; `progress` sees each check as it ends.
pub fn run(ctx: &Context, options: &Options, progress: &mut dyn FnMut(&Check)) -> Report {
    let start = Instant::now();
    let mut v = Verifier {
        ctx,
        quick: options.quick,
        results: Vec::new(),
        progress,
    };
    v.rounding();
    v.limits();
    v.primitives();
    v.builders();
    v.walks();
    v.instances();
    v.hard_cases();
    if ctx.validation_enabled() {
        let messages = ctx.take_validation_messages();
        let detail = messages.first().map(|m| m.to_string()).unwrap_or_default();
        v.record(
            "validation",
            "the layer stayed silent".into(),
            true,
            messages.is_empty(),
            detail,
        );
    }
    let info = ctx.info();
    let mut groups: BTreeMap<&'static str, GroupSummary> = BTreeMap::new();
    for c in &v.results {
        let g = groups.entry(c.group).or_default();
        g.checks += 1;
        if !c.passed && c.required {
            g.failed += 1;
            g.failures.push(format!("{}: {}", c.name, c.detail));
        }
    }
    Report {
        device: info.device.clone(),
        driver: info.driver.clone(),
        checks: v.results.len(),
        failed: groups.values().map(|g| g.failed).sum(),
        groups,
        seconds: start.elapsed().as_secs_f64(),
        results: v.results,
    }
}

struct Verifier<'a> {
    ctx: &'a Context,
    quick: bool,
    results: Vec<Check>,
    progress: &'a mut dyn FnMut(&Check),
}

/// `Ok(None)`: passed; `Ok(Some(why))`: failed; `Err`: the check could not run (a failure).
type Outcome = Result<Option<String>>;

impl Verifier<'_> {
    fn record(
        &mut self,
        group: &'static str,
        name: String,
        required: bool,
        passed: bool,
        detail: String,
    ) {
        let check = Check {
            group,
            name,
            passed,
            required,
            detail,
        };
        (self.progress)(&check);
        self.results.push(check);
    }

    fn check(&mut self, group: &'static str, name: String, outcome: Outcome) {
        let (passed, detail) = match outcome {
            Ok(None) => (true, String::new()),
            Ok(Some(why)) => (false, why),
            Err(e) => (false, format!("error: {e}")),
        };
        self.record(group, name, true, passed, detail);
    }

    fn rounding(&mut self) {
        let f = &self.ctx.info().features;
        if !(f.shader_float64 && f.shader_int64) {
            self.record(
                "rounding",
                "correctly rounded division (needs shaderFloat64 and shaderInt64)".into(),
                false,
                true,
                "skipped: hits may differ from the CPU twin's by an ulp of t".into(),
            );
            return;
        }
        let outcome = rounding_check(self.ctx, if self.quick { 1 << 14 } else { 1 << 18 });
        self.check(
            "rounding",
            "a / b and sqrt(a) equal the CPU's, bit for bit".into(),
            outcome,
        );
    }

    fn limits(&mut self) {
        let budget = self.ctx.info().loop_budget;
        let name = match budget {
            Some(b) => format!("loops run at least {b} iterations, as stated"),
            None => "loops run to their end, as stated".into(),
        };
        let outcome = loop_budget_check(self.ctx);
        self.check("limits", name, outcome);
    }

    fn primitives(&mut self) {
        let ctx = self.ctx;
        let sg = ctx.info().subgroup_size as usize;
        let cfg = PrimConfig::default_for(ctx);
        let wg = cfg.workgroup_size as usize;
        let mut sizes = edge_sizes(sg, wg, cfg.tile() as usize, false);
        if !self.quick {
            sizes.push((1 << 20) + 13);
        }
        let mut rng = Rng::new(0x7e51);
        for &n in &sizes {
            let data: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32 % 1000).collect();
            let floats: Vec<f32> = (0..n).map(|_| rng.range(-1e3, 1e3)).collect();
            let o = scan_check(ctx, cfg, &data);
            self.check("primitives", format!("scan, n = {n}"), o);
            let o = reduce_check(ctx, &data, &floats);
            self.check("primitives", format!("reductions and argmin, n = {n}"), o);
            let keys: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
            let o = sort_check(ctx, cfg, &keys);
            self.check("primitives", format!("radix sort, n = {n}"), o);
        }
    }

    fn builders(&mut self) {
        let ctx = self.ctx;
        let sg = ctx.info().subgroup_size as usize;
        let mut sizes = edge_sizes(sg, 256, 1024, false);
        sizes.extend([2, 3000]);
        if !self.quick {
            sizes.push(30_000);
        }
        sizes.sort_unstable();
        sizes.dedup();
        for kind in [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc] {
            let builder = match AccelBuilder::new(ctx, kind) {
                Ok(b) => b,
                Err(e) => {
                    self.check("builders", format!("{} builder", kind.name()), Err(e));
                    continue;
                }
            };
            for &n in &sizes {
                let g = soup_scene(n, n as u64 + 1, true);
                let o = builder_check(ctx, &builder, &g);
                self.check("builders", format!("{}, {n} primitives", kind.name()), o);
            }
        }
    }

    fn walks(&mut self) {
        let ctx = self.ctx;
        let rays_n = if self.quick { 2_000 } else { 10_000 };
        let mut scenes = vec![("soup", soup_scene(3000, 5, true), soup_rays(rays_n, 9))];
        if let Ok(mesh) = gen::icosphere(5) {
            let tris: Vec<[Vec3; 3]> = mesh
                .indices
                .iter()
                .map(|t| t.map(|i| mesh.positions[i as usize]))
                .collect();
            let g = TraceGeometry::from_triangles(&tris);
            let rays = sphere_rays(rays_n, 11);
            scenes.push(("icosphere", g, rays));
        }
        // Brute force once per scene and query, for every structure and walk.
        let tests = [Intersector::Watertight, Intersector::MollerTrumbore];
        let queries = [Query::Closest, Query::Any];
        let options = |intersector, query| TraceOptions {
            intersector,
            query,
            ..crate::trace::gpu::effective_options(
                ctx,
                &TraceOptions::default(),
                crate::accel::walk::AccelTraversal::KdTree,
            )
        };
        let brute: Vec<Vec<Vec<Hit>>> = scenes
            .iter()
            .map(|(_, g, rays)| {
                tests
                    .iter()
                    .flat_map(|&i| queries.map(|q| (i, q)))
                    .map(|(i, q)| {
                        let opt = options(i, q);
                        rays.iter()
                            .map(|r| cpu::brute_force(g, r, 0.0, &opt))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        for kind in AccelKind::ALL {
            let mut builder = match AccelBuilder::new(ctx, kind) {
                Ok(b) => b,
                Err(e) => {
                    self.check("walks", format!("{} builder", kind.name()), Err(e));
                    continue;
                }
            };
            let walks: &[Traversal] = if kind == AccelKind::KdTree {
                &[Traversal::Stack]
            } else {
                &Traversal::ALL
            };
            for &walk in walks {
                // The wide walk reads a structure built with wide nodes.
                builder = builder.with_wide(walk == Traversal::Wide);
                let accel = kind.walked(walk);
                for (s, (scene, g, rays)) in scenes.iter().enumerate() {
                    let built = (|| {
                        let mut rec = Recorder::new(ctx)?;
                        let (dev, _) = GpuGeometry::record_build(&mut rec, &builder, g, 0)?;
                        rec.submit_and_wait()?;
                        Ok(dev)
                    })();
                    let dev = match built {
                        Ok(d) => d,
                        Err(e) => {
                            let name = format!("{} build over {scene}", accel.label());
                            self.check("walks", name, Err(e));
                            continue;
                        }
                    };
                    for (t, &intersector) in tests.iter().enumerate() {
                        for (q, &query) in queries.iter().enumerate() {
                            let name = format!(
                                "{} over {scene}: {intersector:?} {query:?}",
                                accel.label()
                            );
                            let want = &brute[s][t * queries.len() + q];
                            let o = walk_check(
                                ctx,
                                &dev,
                                accel,
                                &options(intersector, query),
                                rays,
                                want,
                            );
                            self.check("walks", name, o);
                        }
                    }
                }
            }
        }
    }

    fn instances(&mut self) {
        let ctx = self.ctx;
        let f = &ctx.info().features;
        if !(f.buffer_device_address || f.ray_query) {
            let why = "no bufferDeviceAddress: a top level reaches its bottom levels at \
                       device addresses"
                .to_string();
            self.record("instances", "two levels".into(), false, false, why);
            return;
        }
        let sphere = gen::icosphere(2).map(|m| {
            let tris: Vec<[Vec3; 3]> = m
                .indices
                .iter()
                .map(|t| t.map(|i| m.positions[i as usize]))
                .collect();
            TraceGeometry::from_triangles(&tris)
        });
        let Ok(sphere) = sphere else {
            return;
        };
        let hosts = [sphere, soup_scene(200, 3, false)];
        let mut sizes = vec![0, 1, 63, 64, 65];
        if !self.quick {
            sizes.push(1000);
        }
        for n in sizes {
            for steps in [1, 3] {
                let o = instance_boxes_check(ctx, &hosts, n, steps);
                let what = match steps {
                    1 => format!("instance boxes, {n} instances"),
                    _ => format!("instance boxes, {n} instances moving in {steps} steps"),
                };
                self.check("instances", what, o);
            }
        }
        let choices = [
            AccelChoice::new(AccelKind::KdTree, Traversal::Stack),
            AccelChoice::new(AccelKind::SahBvh, Traversal::Stack),
            AccelChoice::new(AccelKind::Lbvh, Traversal::Bitstack),
            AccelChoice::new(AccelKind::Ploc, Traversal::Wide),
        ];
        let rays = instance_rays(if self.quick { 1_000 } else { 4_000 }, 23);
        for choice in choices {
            for intersector in [Intersector::Watertight, Intersector::MollerTrumbore] {
                for query in [Query::Closest, Query::Any] {
                    let name = format!(
                        "two levels over {} bottom levels: {intersector:?} {query:?}",
                        choice.label()
                    );
                    let o =
                        two_level_check(ctx, &hosts, choice, (intersector, query), &rays, false);
                    self.check("instances", name, o);
                }
            }
            let name = format!("moving instances over {} bottom levels", choice.label());
            let how = (Intersector::Watertight, Query::Closest);
            let o = two_level_check(ctx, &hosts, choice, how, &rays, true);
            self.check("instances", name, o);
        }
    }

    fn hard_cases(&mut self) {
        let ctx = self.ctx;
        let size = if self.quick {
            SuiteSize {
                big_soup: 0,
                ..SuiteSize::tiny()
            }
        } else {
            SuiteSize::tiny()
        };
        let mut kinds: Vec<AccelChoice> = AccelKind::ALL
            .iter()
            .map(|&k| AccelChoice::new(k, Traversal::Stack))
            .collect();
        kinds.push(AccelChoice::new(AccelKind::Lbvh, Traversal::Bitstack));
        kinds.push(AccelChoice::new(AccelKind::Ploc, Traversal::Wide));
        let driver = ctx.info().features.ray_query;
        if driver {
            kinds.push(AccelChoice::new(AccelKind::Driver, Traversal::Stack));
        }
        for choice in kinds {
            let required = choice.kind != AccelKind::Driver;
            let label = choice.label();
            match robust::run_all(ctx, &size, &[Intersector::Watertight], choice) {
                Err(e) => self.record(
                    "hard cases",
                    format!("{label}: the suite"),
                    required,
                    false,
                    format!("error: {e}"),
                ),
                Ok(cases) => {
                    for c in cases {
                        // A known limitation is reported, not required (see robust::CaseResult).
                        let required = required && !c.known_limit;
                        let passed = c.failures == 0;
                        let detail = if passed {
                            String::new()
                        } else {
                            format!("{} {} of {} rays", c.failures, c.failure_kind, c.rays)
                        };
                        self.record(
                            "hard cases",
                            format!("{label}: {}", c.case),
                            required,
                            passed,
                            detail,
                        );
                    }
                }
            }
        }
    }
}

/// An object-to-world transform: a turn, a scale (some mirrored, some uneven) and an offset
/// within a 16³ box.
fn instance_transform(rng: &mut Rng) -> [[f32; 4]; 3] {
    let mut u = || rng.next_f32();
    let axis = (Vec3::new(u(), u(), u()) - 0.5).normalize_or(Vec3::Y);
    let turn = glam::Quat::from_axis_angle(axis, u() * std::f32::consts::TAU);
    let s = 0.3 + u();
    let mirror = if u() < 0.25 { -1.0 } else { 1.0 };
    let scale = Vec3::new(s * mirror, s * (0.5 + u()), s);
    let at = (Vec3::new(u(), u(), u()) - 0.5) * 16.0;
    crate::accel::instances::Instance::rows_of(&glam::Affine3A::from_scale_rotation_translation(
        scale, turn, at,
    ))
}

/// Rays from a sphere of radius 20 towards points within the instances' box.
fn instance_rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
    (0..n)
        .map(|_| {
            let o = v().normalize_or(Vec3::X) * 20.0;
            let t = v() * 16.0;
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect()
}

/// Bottom levels over `hosts` built by `choice`'s builder.
fn bottom_levels(
    ctx: &Context,
    hosts: &[TraceGeometry],
    choice: AccelChoice,
) -> Result<Vec<GpuGeometry>> {
    let builder = AccelBuilder::for_choice(ctx, choice)?;
    hosts
        .iter()
        .map(|g| Ok(GpuGeometry::build_fitting(ctx, &builder, g)?.0))
        .collect()
}

/// Instance `i` of a mix in which a top-level build must neutralise every class of invalid
/// instance: every 17th from the 3rd is singular, from the 5th non-finite, from the 7th
/// names a bottom level out of range (9), from the 11th has mask 0 and, given
/// `empty_bottom`, from the 13th names that (empty) bottom level; the rest are `inst`.
pub fn invalid_instance_mix(
    i: usize,
    inst: crate::accel::instances::Instance,
    empty_bottom: Option<u64>,
) -> crate::accel::instances::Instance {
    use crate::accel::instances::Instance;
    match (i % 17, empty_bottom) {
        (3, _) => Instance {
            transform: [[1.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [0.0; 4]],
            ..inst
        },
        (5, _) => Instance {
            transform: [[f32::NAN, 0.0, 0.0, 0.0], [0.0; 4], [0.0; 4]],
            ..inst
        },
        (7, _) => Instance { bottom: 9, ..inst },
        (11, _) => inst.with_mask(0),
        (13, Some(empty)) => Instance {
            bottom: empty,
            ..inst
        },
        _ => inst,
    }
}

/// `accel.instance_boxes` over `n` instances of `hosts`' levels (every 17th an invalid
/// class: singular, non-finite, a bottom level out of range; some with mask 0) moving in
/// `steps` time steps (one more class: singular at the last step only), built in memory of
/// the reported size, against its CPU twin bit for bit, and the count of invalid ones.
fn instance_boxes_check(ctx: &Context, hosts: &[TraceGeometry], n: usize, steps: u32) -> Outcome {
    use crate::accel::instances::{instance_boxes, Instance, InstanceMotion, TopLevelBuilder};
    let levels = bottom_levels(
        ctx,
        hosts,
        AccelChoice::new(AccelKind::Lbvh, Traversal::Stack),
    )?;
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let mut rng = Rng::new(n as u64 + 5);
    let instances: Vec<Instance> = (0..n)
        .map(|i| {
            let inst = Instance::new((i % 2) as u32, instance_transform(&mut rng))
                .with_custom_index(i as u32);
            invalid_instance_mix(i, inst, None)
        })
        .collect();
    // Later steps: each instance moved and turned a little.
    let motion = InstanceMotion::new(steps, 0.5, 2.0);
    let mut all = instances.clone();
    for s in 1..steps as usize {
        all.extend(instances.iter().enumerate().map(|(i, inst)| {
            let mut moved = *inst;
            let turn = glam::Affine3A::from_rotation_y(0.1 * s as f32)
                * glam::Affine3A::from_translation(Vec3::new(s as f32, 0.0, -(s as f32)));
            let m = Instance::affine_of(&inst.transform);
            moved.transform = Instance::rows_of(&(turn * m));
            if i % 17 == 13 && s + 1 == steps as usize {
                moved.transform = [[0.0; 4]; 3];
            }
            moved
        }));
    }
    let instances = all;
    let builder = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?;
    let flags = crate::accel::embedded::BuildFlags::default();
    let sizes = builder.sizes_for_motion(ctx, n as u32, refs.len(), motion, &flags)?;
    let memory = Buffer::<u8>::arena(ctx, "verify.top", sizes.structure_bytes as usize)?;
    let scratch = Buffer::<u8>::arena(ctx, "verify.scratch", sizes.build_scratch_bytes as usize)?;
    let input = Buffer::<Instance>::new(ctx, "verify.instances", instances.len().max(1))?;
    let mut top =
        builder.create_moving_in(ctx, &refs, n as u32, motion, &flags, memory.own_range())?;
    let mut rec = Recorder::new(ctx)?;
    rec.upload(&input, &instances)?;
    rec.transfer_to_compute();
    builder.record_build_from(
        &mut rec,
        &mut top,
        input.own_range(),
        n as u32,
        scratch.own_range(),
    )?;
    rec.compute_to_transfer();
    let status = top.record_read_status(&mut rec)?;
    rec.transfer_to_host();
    rec.submit_and_wait()?;
    let infos: Vec<_> = levels
        .iter()
        .map(|l| Ok((l.accel.info.download()?[0], l.reference()?)))
        .collect::<Result<_>>()?;
    let (boxes, records) = top.download()?;
    let want = instance_boxes(
        &instances,
        motion,
        &infos,
        Some(top.bottom_handles_address()),
    );
    let (want_boxes, want_records, invalid) = (want.boxes, want.records, want.invalid);
    let bits_of = |r: &[[[f32; 4]; 3]]| -> Vec<u32> {
        r.iter().flatten().flatten().map(|x| x.to_bits()).collect()
    };
    if bits_of(&top.download_steps()?) != bits_of(&want.steps) {
        return Ok(Some("the steps differ from their CPU twin's".into()));
    }
    let bits = |b: &[[f32; 6]]| -> Vec<u32> { b.iter().flatten().map(|x| x.to_bits()).collect() };
    if let Some(i) = (0..n).find(|&i| bits(&boxes[i..=i]) != bits(&want_boxes[i..=i])) {
        return Ok(Some(format!(
            "instance {i}: box {:?}, its CPU twin's {:?}",
            boxes[i], want_boxes[i]
        )));
    }
    if let Some(i) = (0..n).find(|&i| records[i] != want_records[i]) {
        return Ok(Some(format!(
            "instance {i}: record {:?}, its CPU twin's {:?}",
            records[i], want_records[i]
        )));
    }
    let got = status.read()?.invalid_primitives;
    Ok((got != invalid).then(|| format!("{got} invalid instances counted, {invalid} expected")))
}

/// 30 instances of `hosts`' levels built by `choice`'s builder (`moving`: in three time
/// steps, traced at a time between two), traced through the two-level walk, against its CPU
/// twin with brute force in each bottom level: the same instance and primitive (or a tie), t
/// within 1e-5; any hit: the same hit or miss.
fn two_level_check(
    ctx: &Context,
    hosts: &[TraceGeometry],
    choice: AccelChoice,
    (intersector, query): (Intersector, Query),
    rays: &[Ray],
    moving: bool,
) -> Outcome {
    use crate::accel::instances::{Instance, InstanceMotion, TopLevelBuilder};
    use crate::accel::walk::AccelTraversal;
    use crate::trace::gpu::effective_options;
    use crate::trace::instanced::trace_instances;
    let levels = bottom_levels(ctx, hosts, choice)?;
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let mut rng = Rng::new(29);
    let n = 30;
    let instances: Vec<Instance> = (0..n)
        .map(|i| Instance::new(i % 2, instance_transform(&mut rng)).with_custom_index(i))
        .collect();
    let (motion, time) = match moving {
        true => (InstanceMotion::new(3, 0.0, 1.0), 0.7),
        false => (InstanceMotion::STATIC, 0.0),
    };
    // Later steps: each instance moved and turned a little.
    let mut records = instances.clone();
    for s in 1..motion.steps {
        records.extend(instances.iter().map(|inst| {
            let turn = glam::Affine3A::from_rotation_z(0.2 * s as f32)
                * glam::Affine3A::from_translation(Vec3::new(0.0, 0.5 * s as f32, 0.0));
            Instance {
                transform: Instance::rows_of(&(turn * Instance::affine_of(&inst.transform))),
                ..*inst
            }
        }));
    }
    let top = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?.build_moving(
        ctx,
        &refs,
        &records,
        motion,
        &Default::default(),
    )?;
    // Hit ids as instance · STRIDE + primitive.
    const STRIDE: u32 = 100_000;
    let first: Vec<u32> = (0..n).map(|i| i * STRIDE).collect();
    let walk = choice.traversal();
    let opt = effective_options(
        ctx,
        &TraceOptions {
            intersector,
            query,
            ..TraceOptions::default()
        },
        walk,
    );
    let bitstack = walk == AccelTraversal::Bvh(Traversal::Bitstack);
    let batch = crate::trace::instanced::trace_top_level(
        ctx,
        &top,
        crate::accel::two_levels::SceneIds {
            mesh_first: &first,
            ..Default::default()
        },
        &opt,
        bitstack,
        rays,
        time,
    )?;
    if batch.exhausted > 0 {
        return Ok(Some(format!("{} rays ran out of steps", batch.exhausted)));
    }
    let (_, records) = top.download()?;
    let steps = top.download_steps()?;
    let mut wrong = 0;
    let mut example = None;
    for (i, (r, got)) in rays.iter().zip(&batch.hits).enumerate() {
        let want = trace_instances(
            &records,
            &steps,
            r,
            time,
            0xff,
            query == Query::Any,
            |b, ro| (cpu::brute_force(&hosts[b as usize], ro, 0.0, &opt), false),
        );
        let same = match query {
            Query::Any => got.is_hit() == want.hit.is_hit(),
            Query::Closest => {
                let local = match got.is_hit() {
                    true => Hit {
                        prim: got.prim % STRIDE,
                        ..*got
                    },
                    false => *got,
                };
                let instance = got.is_hit().then_some(got.prim / STRIDE);
                robust::same_answer(&local, &want.hit)
                    && (instance == want.instance || local.t == want.hit.t)
            }
        };
        if !same {
            wrong += 1;
            example.get_or_insert(format!("ray {i}: {got:?} vs the twin's {want:?}"));
        }
    }
    Ok(example.map(|e| format!("{wrong} of {} rays differ; {e}", rays.len())))
}

/// Triangles scattered in a 10³ box (and spheres beside them when `spheres`).
fn soup_scene(n: usize, seed: u64, spheres: bool) -> TraceGeometry {
    let mut rng = Rng::new(seed);
    let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    let tris: Vec<[Vec3; 3]> = (0..n)
        .map(|_| {
            let c = v() * 10.0;
            [c, c + v(), c + v()]
        })
        .collect();
    let s: Vec<Vec4> = if spheres {
        (0..n.div_ceil(7))
            .map(|i| Vec4::new(i as f32 % 11.0, (i % 5) as f32, -3.0, 0.4))
            .collect()
    } else {
        Vec::new()
    };
    TraceGeometry::from_triangles_and_spheres(&tris, &s)
}

/// Rays from around the soup's box in random directions, some of them axis-parallel with
/// ±0 components.
fn soup_rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 14.0 - 2.0;
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            if i % 5 == 0 {
                let axis = i / 5 % 3;
                d = Vec3::ZERO;
                d[axis] = if i % 2 == 0 { 1.0 } else { -1.0 };
                d[(axis + 1) % 3] = -0.0;
            }
            Ray::new(o, d, 0.0, f32::INFINITY)
        })
        .collect()
}

/// Rays at the unit sphere from outside and from inside.
fn sphere_rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = if i % 2 == 0 {
                rng.vec3_signed() * 3.0
            } else {
                rng.vec3_signed() * 0.5
            };
            let target = rng.vec3_signed() * 0.8;
            Ray::new(o, target - o, 0.0, f32::INFINITY)
        })
        .collect()
}

fn rounding_check(ctx: &Context, n: usize) -> Outcome {
    let pairs = rounding_pairs(n);
    let refine = !ctx.info().ieee_division;
    let got = run_rounding_probe(ctx, &kernels::GPU_ROUNDING_PROBE_EXACT, refine, &pairs)?;
    Ok(rounding_mismatch(&pairs, &got).err())
}

/// A loop of 2^20 trips (`glsl/gpu/loop_probe.comp`) against the device's stated loop
/// budget: a driver that ends loops silently below the walks' step cap would turn rays
/// into silent misses.
fn loop_budget_check(ctx: &Context) -> Outcome {
    let n = 1 << 20;
    let trips = loop_trips(ctx, n)?;
    let stated = ctx.info().loop_budget;
    // A stated budget the loop did not hit only lowers the step cap (safe); a budget the
    // loop hits below what is stated ends walks silently.
    let ok = match stated {
        Some(b) => trips >= b.min(n),
        None => trips == n,
    };
    Ok((!ok).then(|| {
        format!(
            "a loop of {n} trips ran {trips} on the device; its stated loop budget is {stated:?}"
        )
    }))
}

/// The iterations a loop of `n` trips really runs in one invocation.
pub fn loop_trips(ctx: &Context, n: u32) -> Result<u32> {
    let kernel = ctx.kernel(&kernels::GPU_LOOP_PROBE, &Spec::new())?;
    let out = Buffer::<u32>::zeroed(ctx, "verify.loop.out", 2)?;
    let mut rec = Recorder::new(ctx)?;
    rec.dispatch(&kernel, [1, 1, 1], &[&out], &n);
    rec.compute_to_transfer();
    rec.submit_and_wait()?;
    Ok(out.download()?[0])
}

/// `n` operand pairs for the rounding probe: reciprocals (the slab tests' 1 / d), quotients
/// near 1, random ones over 2^±60, and a few exact cases.
pub fn rounding_pairs(n: usize) -> Vec<[f32; 2]> {
    let mut rng = Rng::new(0x05ee_dd1f);
    let mut any = || {
        let r = rng.next_u64();
        let e = ((r >> 32) % 120) as i32 - 60;
        let sign = (r as u32 & 1) << 31;
        f32::from_bits(sign | (((127 + e) as u32) << 23) | (r as u32 >> 9))
    };
    let mut pairs: Vec<[f32; 2]> = (0..n)
        .map(|i| {
            let b = any();
            let a = match i % 4 {
                0 => 1.0,
                1 => b * f32::from_bits(0x3f80_0000 + (i as u32 % 16)),
                _ => any(),
            };
            [a, b]
        })
        .collect();
    let exact = [
        1.0f32,
        2.0,
        0.5,
        3.0,
        4.0,
        1.0 - f32::EPSILON / 2.0,
        1.0 + f32::EPSILON,
    ];
    for x in exact {
        pairs.extend([[x, 1.0], [x, 3.0], [1.0, x]]);
    }
    pairs
}

/// `div_rn` and `sqrt_rn` of every pair by a variant of `glsl/gpu/rounding_probe.comp`,
/// with the refinement on or off (spec constant 21): (quotient bits, square-root bits).
pub fn run_rounding_probe(
    ctx: &Context,
    variant: &'static crate::gpu::ShaderBlob,
    refine: bool,
    pairs: &[[f32; 2]],
) -> Result<Vec<[u32; 2]>> {
    let n = pairs.len();
    let kernel = ctx.kernel(variant, &Spec::new().workgroup(64).u32(21, refine as u32))?;
    let input = Buffer::from_slice(ctx, "verify.rounding.in", pairs)?;
    let out = Buffer::<[u32; 2]>::zeroed(ctx, "verify.rounding.out", n)?;
    let mut rec = Recorder::new(ctx)?;
    let groups = rec.groups_1d(n as u64, 64);
    rec.dispatch(&kernel, groups, &[&input, &out], &(n as u32));
    rec.compute_to_transfer();
    rec.submit_and_wait()?;
    out.download()
}

/// The probe's answers against the CPU's IEEE ones, where operands and results are normal
/// and well inside the range: the quotients compared, or the first difference.
pub fn rounding_mismatch(
    pairs: &[[f32; 2]],
    got: &[[u32; 2]],
) -> std::result::Result<usize, String> {
    let in_range = |x: f32| x.is_finite() && (1e-30..=1e30).contains(&x.abs());
    let mut compared = 0;
    for (&[a, b], &[q, s]) in pairs.iter().zip(got) {
        let (want_q, want_s) = (a / b, a.abs().sqrt());
        if !in_range(a) {
            continue;
        }
        if in_range(want_q) && in_range(b) {
            if q != want_q.to_bits() {
                let gpu = f32::from_bits(q);
                return Err(format!(
                    "{a:e} / {b:e} = {gpu:e} on the GPU, {want_q:e} on the CPU"
                ));
            }
            compared += 1;
        }
        if s != want_s.to_bits() {
            let gpu = f32::from_bits(s);
            return Err(format!(
                "sqrt {a:e} = {gpu:e} on the GPU, {want_s:e} on the CPU"
            ));
        }
    }
    Ok(compared)
}

fn scan_check(ctx: &Context, cfg: PrimConfig, data: &[u32]) -> Outcome {
    let scan = Scan::new(ctx, cfg, ScanInput::U32)?;
    for op in [ScanOp::Exclusive, ScanOp::Inclusive] {
        let got = scan.run_u32(ctx, data, op)?;
        let want = scan::scan_cpu(data, op);
        if got != want {
            let at = got.0.iter().zip(&want.0).position(|(a, b)| a != b);
            return Ok(Some(format!(
                "{op:?}: first difference at {at:?}, totals {} vs {}",
                got.1, want.1
            )));
        }
    }
    Ok(None)
}

fn reduce_check(ctx: &Context, data: &[u32], floats: &[f32]) -> Outcome {
    let cfg = reduce::recommended_config(ctx);
    let r = Reduce::new(ctx, cfg)?;
    let pairs = [
        ("sum_u32", r.sum_u32(ctx, data)?, reduce::sum_u32_cpu(data)),
        ("min_u32", r.min_u32(ctx, data)?, reduce::min_u32_cpu(data)),
        ("max_u32", r.max_u32(ctx, data)?, reduce::max_u32_cpu(data)),
        (
            "sum_f32",
            r.sum_f32(ctx, floats)?.to_bits(),
            reduce::sum_f32_cpu(floats, cfg).to_bits(),
        ),
        (
            "min_f32",
            r.min_f32(ctx, floats)?.to_bits(),
            reduce::min_f32_cpu(floats).to_bits(),
        ),
        (
            "max_f32",
            r.max_f32(ctx, floats)?.to_bits(),
            reduce::max_f32_cpu(floats).to_bits(),
        ),
    ];
    for (name, got, want) in pairs {
        if got != want {
            return Ok(Some(format!(
                "{name}: {got:#x} on the GPU, {want:#x} on the CPU"
            )));
        }
    }
    let got = r.argmin(ctx, floats)?;
    let want = reduce::argmin_cpu(floats);
    if got.0.to_bits() != want.0.to_bits() || got.1 != want.1 {
        return Ok(Some(format!(
            "argmin: {got:?} on the GPU, {want:?} on the CPU"
        )));
    }
    Ok(None)
}

fn sort_check(ctx: &Context, cfg: PrimConfig, keys: &[u32]) -> Outcome {
    let sort = RadixSort::new(ctx, cfg, DEFAULT_BITS_PER_PASS)?;
    let values: Vec<u32> = (0..keys.len() as u32).collect();
    let got = sort.sort_u32(ctx, keys, &values)?;
    let want = radix_sort::radix_sort_cpu(keys, &values);
    if got != want {
        let at = got.1.iter().zip(&want.1).position(|(a, b)| a != b);
        return Ok(Some(format!("first difference at {at:?}")));
    }
    Ok(None)
}

fn builder_check(ctx: &Context, builder: &AccelBuilder, g: &TraceGeometry) -> Outcome {
    // A kd-tree that ran out of its reference budget is built again with twice the budget,
    // as a caller does (the build says so on the device).
    let (dev, _) = GpuGeometry::build_fitting(ctx, builder, g)?;
    let host = dev.accel.download()?;
    if let HostStructure::Bvh(tree) = &host {
        if let Err(e) = bvh::validate::validate(tree, &g.boxes) {
            return Ok(Some(format!("invalid: {e}")));
        }
    }
    let equal = host == builder.host_twin(g)?;
    Ok((!equal).then(|| "differs from its CPU twin".to_string()))
}

fn walk_check(
    ctx: &Context,
    dev: &GpuGeometry,
    accel: crate::accel::walk::AccelTraversal,
    opt: &TraceOptions,
    rays: &[Ray],
    brute: &[Hit],
) -> Outcome {
    let tracer = Tracer::for_accel(ctx, opt, accel)?;
    if tracer.options().exact != opt.exact {
        return Ok(Some(
            "the walk cannot run the brute force's arithmetic".into(),
        ));
    }
    let batch = tracer.trace(ctx, dev, rays, 0.0)?;
    if batch.exhausted > 0 {
        return Ok(Some(format!("{} rays ran out of steps", batch.exhausted)));
    }
    let mut wrong = 0;
    let mut first = None;
    for (i, (got, want)) in batch.hits.iter().zip(brute).enumerate() {
        let same = match opt.query {
            Query::Closest => robust::same_answer(got, want),
            Query::Any => got.is_hit() == want.is_hit(),
        };
        if !same {
            wrong += 1;
            first.get_or_insert(format!("ray {i}: {got:?} vs brute force {want:?}"));
        }
    }
    Ok(first.map(|f| format!("{wrong} of {} rays differ; {f}", rays.len())))
}
