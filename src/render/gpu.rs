//! The wavefront renderer on the GPU: per sample, per wave of pixels, camera rays, then per
//! bounce extend (closest hit) → shade → shadow (any hit) → accumulate → compact the live
//! children (the compaction primitive) → gather, all recorded into one command buffer per
//! sample with ray counts and dispatch sizes kept on the GPU (indirect dispatch).

use std::sync::Arc;

use crate::accel::device::{AccelBuilder, AccelKind, RecordedBuild};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::walk::AccelTraversal;
use crate::accel::walk::Traversal;
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, Kernel, Profile, Recorder, Result, Spec, Traffic,
};
use crate::prims::compact::{Compact, CompactScratch};
use crate::prims::scan::GpuCount;
use crate::prims::PrimConfig;
use crate::trace::gpu::{effective_options, traversal_spec};
use crate::trace::{Hit, Query, TraceOptions};

use super::plan::Plan;
use super::types::{counter, PathRay, ShadowRay};
use super::{RayCounts, RenderAccel, RenderScene};
use crate::accel::host::HostStructure;

mod frames;
mod levels;
pub use frames::{FrameImage, FrameLoop, Update};
use levels::{Levels, Top, Traced};

const WG: u32 = 64;

struct Kernels {
    camera: Arc<Kernel>,
    extend: Arc<Kernel>,
    shade: Arc<Kernel>,
    shadow: Arc<Kernel>,
    accumulate: Arc<Kernel>,
    advance: Arc<Kernel>,
    gather: Arc<Kernel>,
    tonemap: Arc<Kernel>,
    /// Extend and shadow, and shade, over two levels (plans that trace two levels).
    instances: Option<Arc<Kernel>>,
    /// The driver's two levels: its hits mapped to instances (plans over them).
    driver_hits: Option<Arc<Kernel>>,
    shade_levels: Option<Arc<Kernel>>,
}

/// Kernels specialised for one plan.
pub struct Renderer {
    k: Kernels,
    compact: Compact,
    /// How the kernels walk the structure (a host BVH walked wide is uploaded with its wide
    /// nodes).
    walk: AccelTraversal,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CameraPush {
    first_pixel: u32,
    pixels: u32,
    sample: u32,
    wg: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct InstancesPush {
    shadow: u32,
    pad: u32,
    handle: u64,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TonemapPush {
    n: u32,
    inv_spp: f32,
}

/// Device buffers of one render.
struct Frame {
    params: Buffer<super::types::RenderParams>,
    geom: Traced,
    materials: Buffer<super::types::GpuMaterial>,
    lights: Buffer<super::types::GpuLight>,
    prim_material: Buffer<u32>,
    tri_normals: Buffer<f32>,
    queue: Buffer<PathRay>,
    hits: Buffer<Hit>,
    radiance: Buffer<[f32; 4]>,
    shadows: Buffer<ShadowRay>,
    children: Buffer<PathRay>,
    flags: Buffer<u8>,
    iota: Buffer<u32>,
    live: Buffer<u32>,
    compact: CompactScratch,
    counters: Buffer<u32>,
    accum: Buffer<[f32; 4]>,
    /// `accum` and `counters` before the current sample, restored when it overflows.
    accum_before: Buffer<[f32; 4]>,
    counters_before: Buffer<u32>,
    pixels: Buffer<u32>,
}

/// A finished render on the GPU.
pub struct GpuRender {
    /// Mean radiance per pixel (linear), row-major from the top-left.
    pub radiance: Vec<[f32; 3]>,
    /// 8-bit sRGB RGBA.
    pub rgba: Vec<u8>,
    /// Rays traced per kind over every sample (a redone sample counted once).
    pub counts: RayCounts,
    /// GPU timestamps of the render's submissions (`render.*` scopes, the build's).
    pub profile: Profile,
    /// Samples redone with smaller waves after a queue overflow.
    pub redone_samples: u32,
    /// Milliseconds of a structure built on the device ([`RenderAccel::OnDevice`]): the GPU
    /// passes, or a host builder's time.
    pub build_ms: Option<f64>,
    /// Submissions and read-backs of the whole render, build included.
    pub traffic: Traffic,
    /// Builds on the device: 1, plus one per kd-tree build that ran out of its reference
    /// budget (its sample is redone after a build with twice the budget).
    pub build_attempts: u32,
    /// Bytes read back before the first rays were traced (0: the build, the uploads and the
    /// first sample are one submission).
    pub readback_before_trace: u64,
}

/// The mean radiance per pixel from the accumulated sums of `spp` samples: one helper, so a
/// still render and an animation's frame of the same scene agree bit for bit.
pub(crate) fn mean_radiance(accum: &[[f32; 4]], spp: u32) -> Vec<[f32; 3]> {
    let inv = 1.0 / spp as f32;
    accum
        .iter()
        .map(|a| [a[0] * inv, a[1] * inv, a[2] * inv])
        .collect()
}

/// Records the undo of a sample: `accum` and `counters` as they were before it.
fn restore(rec: &mut Recorder, f: &Frame, pixels: u32) {
    rec.compute_to_transfer();
    rec.copy(&f.accum_before, &f.accum, pixels as usize);
    rec.copy(&f.counters_before, &f.counters, counter::WORDS);
    rec.transfer_to_transfer();
}

/// A kernel's bindings: `head`, then the geometry buffers `traverse.glsl` declares, then
/// `tail`.
fn around_geometry<'a>(
    head: &[&'a dyn BufferArg],
    geometry: &[&'a dyn BufferArg],
    tail: &[&'a dyn BufferArg],
) -> Vec<&'a dyn BufferArg> {
    [head, geometry, tail].concat()
}

impl Renderer {
    /// Compiles the kernels specialised for `plan` and the walk of `plan.accel`; errors where
    /// the device lacks what the walk needs or a kernel fails to build.
    pub fn new(ctx: &Context, plan: &Plan, trace: &TraceOptions) -> Result<Self> {
        let walk = plan.accel.traversal();
        walk.require(ctx)?;
        let opt = effective_options(ctx, trace, walk);
        let closest = traversal_spec(
            ctx,
            &TraceOptions {
                query: Query::Closest,
                ..opt
            },
        )
        .u32(20, walk.spec())
        .workgroup(WG);
        let any = traversal_spec(
            ctx,
            &TraceOptions {
                query: Query::Any,
                ..opt
            },
        )
        .u32(20, walk.spec())
        .workgroup(WG);
        let b = |v: bool| v as u32;
        let shade = Spec::new()
            .workgroup(WG)
            .u32(4, b(plan.lights))
            .u32(5, b(plan.area_lights))
            .u32(6, b(plan.reflection))
            .u32(7, b(plan.refraction))
            .u32(8, b(plan.glossy))
            .u32(9, b(plan.ambient_occlusion))
            .u32(10, b(plan.emission))
            .u32(11, b(plan.bounces));
        let camera = Spec::new()
            .workgroup(WG)
            .u32(1, b(plan.thin_lens))
            .u32(2, b(plan.jitter))
            .u32(3, b(plan.motion));
        let plain = Spec::new().workgroup(WG);
        let nodes = crate::accel::walk::NodeAccess::for_device(ctx);
        let extend = walk.variant(
            opt.exact,
            nodes,
            [
                &kernels::RENDER_EXTEND_EXACT,
                &kernels::RENDER_EXTEND_FLOAT,
                &kernels::RENDER_EXTEND_QUERY,
                &kernels::RENDER_EXTEND_EXACT_TEXEL,
                &kernels::RENDER_EXTEND_FLOAT_TEXEL,
            ],
        );
        let shadow = walk.variant(
            opt.exact,
            nodes,
            [
                &kernels::RENDER_SHADOW_EXACT,
                &kernels::RENDER_SHADOW_FLOAT,
                &kernels::RENDER_SHADOW_QUERY,
                &kernels::RENDER_SHADOW_EXACT_TEXEL,
                &kernels::RENDER_SHADOW_FLOAT_TEXEL,
            ],
        );
        let (instances, driver_hits, shade_levels) = match (plan.levels, walk) {
            // The driver's levels: its query walks them in the flat kernels.
            (2, AccelTraversal::RayQuery) => (
                None,
                Some(ctx.kernel(&kernels::RENDER_DRIVER_HITS, &plain)?),
                Some(ctx.kernel(&kernels::RENDER_SHADE_LEVELS, &shade)?),
            ),
            (2, _) => (
                Some(instances_kernel(
                    ctx,
                    &opt,
                    walk == AccelTraversal::Bvh(Traversal::Bitstack),
                )?),
                None,
                Some(ctx.kernel(&kernels::RENDER_SHADE_LEVELS, &shade)?),
            ),
            _ => (None, None, None),
        };
        Ok(Self {
            k: Kernels {
                instances,
                driver_hits,
                shade_levels,
                camera: ctx.kernel(&kernels::RENDER_CAMERA, &camera)?,
                extend: ctx.kernel(extend, &walk.spec_for(closest, extend))?,
                shade: ctx.kernel(&kernels::RENDER_SHADE_FLAT, &shade)?,
                shadow: ctx.kernel(shadow, &walk.spec_for(any, shadow))?,
                accumulate: ctx.kernel(&kernels::RENDER_ACCUMULATE, &plain)?,
                advance: ctx.kernel(&kernels::RENDER_ADVANCE, &Spec::new())?,
                gather: ctx.kernel(&kernels::RENDER_GATHER, &plain)?,
                tonemap: ctx.kernel(&kernels::RENDER_TONEMAP, &plain)?,
            },
            compact: Compact::new(ctx, PrimConfig::default_for(ctx))?,
            walk,
        })
    }

    /// The render's buffers, their contents uploaded by commands recorded into `rec`.
    fn frame(
        &self,
        rec: &mut Recorder,
        rs: &RenderScene,
        plan: &Plan,
        geom: Traced,
    ) -> Result<Frame> {
        let ctx = &rec.context().clone();
        let cap = plan.queue_capacity;
        let slots = plan.shadow_slots as usize;
        let pixels = plan.width as usize * plan.height as usize;
        // Two child slots per queue ray, and the compaction's arrays over them, where rays
        // bounce (else the kernels that touch them never run or never reach them).
        let child_slots = if plan.bounces { 2 * cap } else { 1 };
        let iota: Vec<u32> = (0..child_slots as u32).collect();
        // Over two levels the per-primitive arrays are the levels' own (`Levels`).
        let levels = matches!(geom, Traced::Levels(_));
        let (n_materials, n_normals) = match levels {
            true => (0, 0),
            false => (rs.prim_material.len(), rs.tri_normals.len()),
        };
        let f = Frame {
            params: Buffer::new(ctx, "render.params", 1)?,
            geom,
            materials: Buffer::new(ctx, "render.materials", rs.materials.len())?,
            lights: Buffer::new(ctx, "render.lights", rs.lights.len())?,
            prim_material: Buffer::new(ctx, "render.prim_material", n_materials)?,
            tri_normals: Buffer::new(ctx, "render.tri_normals", n_normals)?,
            queue: Buffer::new(ctx, "render.queue", cap)?,
            hits: Buffer::new(ctx, "render.hits", cap)?,
            radiance: Buffer::new(ctx, "render.radiance", cap)?,
            shadows: Buffer::new(ctx, "render.shadows", (cap * slots).max(1))?,
            children: Buffer::new(ctx, "render.children", child_slots)?,
            flags: Buffer::new(ctx, "render.flags", child_slots)?,
            iota: Buffer::new(ctx, "render.iota", iota.len())?,
            live: Buffer::new(ctx, "render.live", child_slots)?,
            compact: self.compact.scratch(ctx, child_slots)?,
            counters: Buffer::new(ctx, "render.counters", counter::WORDS)?,
            accum: Buffer::new(ctx, "render.accum", pixels)?,
            accum_before: Buffer::new(ctx, "render.accum_before", pixels)?,
            counters_before: Buffer::new(ctx, "render.counters_before", counter::WORDS)?,
            pixels: Buffer::new(ctx, "render.pixels", pixels)?,
        };
        rec.upload(&f.params, &[rs.params])?;
        rec.upload(&f.materials, &rs.materials)?;
        rec.upload(&f.lights, &rs.lights)?;
        if !levels {
            rec.upload(&f.prim_material, &rs.prim_material)?;
            rec.upload(&f.tri_normals, &rs.tri_normals)?;
        }
        rec.upload(&f.iota, &iota)?;
        rec.fill(&f.flags, 0);
        rec.fill(&f.counters, 0);
        rec.fill(&f.accum, 0);
        // The first sample copies `accum` and `counters` (a transfer) before its kernels.
        rec.transfer_to_transfer();
        rec.transfer_to_compute();
        Ok(f)
    }

    /// Records what a frame of an animation changes in `f` before its samples: the frame's
    /// constants and shading normals (over two levels the instances' placements), and zeroed
    /// accumulators, counters and flags.
    fn record_reset(&self, rec: &mut Recorder, f: &Frame, rs: &RenderScene) -> Result<()> {
        rec.compute_to_transfer();
        rec.upload(&f.params, &[rs.params])?;
        match (&f.geom, &rs.levels) {
            // (the normals are the bottom levels': they do not move)
            (Traced::Levels(l), Some(rl)) => l.record_placements(rec, rl)?,
            _ => rec.upload(&f.tri_normals, &rs.tri_normals)?,
        }
        rec.fill(&f.flags, 0);
        rec.fill(&f.counters, 0);
        rec.fill(&f.accum, 0);
        rec.transfer_to_compute();
        Ok(())
    }

    /// The geometry and its structures on the device, and the recorder of the first
    /// submission: a structure built on the device ([`RenderAccel::OnDevice`]) is recorded
    /// into it, so it is built and traced in one submission with nothing read back between
    /// (two levels: the bottom levels' builds, then the top level's); a host
    /// structure is uploaded.
    fn geometry(
        &self,
        ctx: &Context,
        (rs, plan): (&RenderScene, &Plan),
        grow: u32,
    ) -> Result<(Traced, Recorder, Option<RecordedBuild>)> {
        let mut rec = Recorder::new(ctx)?;
        let flat = Traced::Flat;
        Ok(match (&rs.accel, &rs.levels) {
            (RenderAccel::OnDevice(choice), Some(rl)) => {
                let sizes = (grow, plan.queue_capacity);
                let shading = (rl, &rs.prim_material[..], &rs.tri_normals[..]);
                let levels = Levels::record_build(&mut rec, *choice, shading, sizes, false)?;
                let built = RecordedBuild { host_ms: None };
                (Traced::Levels(levels), rec, Some(built))
            }
            (RenderAccel::Host(HostStructure::KdTree(tree)), _) => (
                flat(GpuGeometry::upload(ctx, &rs.geometry, tree)?),
                rec,
                None,
            ),
            (RenderAccel::Host(HostStructure::Bvh(bvh)), _)
                if self.walk == AccelTraversal::Bvh(Traversal::Wide) =>
            {
                (
                    flat(GpuGeometry::upload_wide_bvh(ctx, &rs.geometry, bvh)?),
                    rec,
                    None,
                )
            }
            (RenderAccel::Host(HostStructure::Bvh(bvh)), _) => (
                flat(GpuGeometry::upload_bvh(ctx, &rs.geometry, bvh)?),
                rec,
                None,
            ),
            (RenderAccel::OnDevice(choice), None) => {
                let builder = AccelBuilder::for_choice(ctx, *choice)?;
                let (geom, recorded) =
                    GpuGeometry::record_build(&mut rec, &builder, &rs.geometry, grow)?;
                (flat(geom), rec, Some(recorded))
            }
        })
    }

    /// Renders `plan.spp` samples; `progress(done)` is called after each sample.
    pub fn render(
        &self,
        ctx: &Context,
        rs: &RenderScene,
        plan: &Plan,
        progress: impl FnMut(u32),
    ) -> Result<GpuRender> {
        self.render_from(ctx, rs, plan, progress, None)
    }

    /// [`Renderer::render`] of a scene it takes, the same image: a scene whose rest is in
    /// pieces has its bottom levels built one after another, each in submissions of its own
    /// before the first sample's (`Levels::record_build_in_pieces`), and lets go of each
    /// piece's host geometry and of the host's copies of what shading reads as they reach
    /// the device, so that the host holds the scene's primitives at most once besides the
    /// device's copy (on a device whose memory is host memory, lavapipe, what that saves
    /// is most of the render's memory).
    pub fn render_owned(
        &self,
        ctx: &Context,
        mut rs: RenderScene,
        plan: &Plan,
        progress: impl FnMut(u32),
    ) -> Result<GpuRender> {
        let choice = match (&rs.accel, &rs.levels) {
            (RenderAccel::OnDevice(c), Some(rl))
                if c.kind != AccelKind::Driver && rl.scene.rest_first.len() > 1 =>
            {
                *c
            }
            _ => return self.render(ctx, &rs, plan, progress),
        };
        let start = ctx.traffic();
        let mut rec = Recorder::new(ctx)?;
        let shading = (
            std::mem::take(&mut rs.prim_material),
            std::mem::take(&mut rs.tri_normals),
        );
        let rl = rs.levels.as_mut().expect("two levels");
        let levels =
            Levels::record_build_in_pieces(&mut rec, choice, rl, shading, plan.queue_capacity)?;
        let built = (Traced::Levels(levels), rec, start);
        self.render_from(ctx, &rs, plan, progress, Some(built))
    }

    /// [`Renderer::render`], with the structures built already where `built` has them (and
    /// the recorder of the first submission, and the traffic before their build).
    fn render_from(
        &self,
        ctx: &Context,
        rs: &RenderScene,
        plan: &Plan,
        mut progress: impl FnMut(u32),
        built: Option<(Traced, Recorder, Traffic)>,
    ) -> Result<GpuRender> {
        let start = built.as_ref().map_or_else(|| ctx.traffic(), |b| b.2);
        let mut grow = 0;
        let prebuilt = built.is_some();
        let (geom, first, mut recorded) = match built {
            Some((geom, rec, _)) => (geom, rec, Some(RecordedBuild { host_ms: None })),
            None => self.geometry(ctx, (rs, plan), grow)?,
        };
        let mut pending = Some(first);
        let mut f = self.frame(
            pending.as_mut().expect("the first recorder"),
            rs,
            plan,
            geom,
        )?;
        let readback_before_trace = ctx.traffic().readback_bytes - start.readback_bytes;
        let mut build_ms = None;
        let mut profile = Profile::default();
        let pixels = plan.width * plan.height;
        let mut wave_pixels = plan.wave_pixels;
        let mut redone_samples = 0;
        let mut sample = 0;
        let mut warmed = false;
        while sample < plan.spp {
            let mut rec = match pending.take() {
                Some(rec) => rec,
                None => Recorder::new(ctx)?,
            };
            if !warmed {
                // Every kernel of a sample and the tone map, dispatched empty before the
                // first timed sample: their code is compiled here, not inside sample 0.
                rec.warm_up(|rec| {
                    self.record_sample(rec, &f, plan, wave_pixels, sample, false);
                    self.record_tonemap(rec, &f, plan);
                });
                warmed = true;
            }
            self.record_sample(&mut rec, &f, plan, wave_pixels, sample, true);
            rec.compute_to_transfer();
            let built = match build_ms {
                None => f.geom.record_read_built(&mut rec)?,
                Some(_) => Vec::new(),
            };
            let counters = rec.read_back(&f.counters)?;
            rec.transfer_to_host();
            let p = rec.submit_and_wait()?;
            if Traced::kd_overflow(built)? {
                // The kd-tree ran out of references: every ray of the sample missed.
                // Undo the sample and build again with twice the budget.
                grow += 1;
                // (bottom levels built ahead were built until they fit)
                if grow > 8 || prebuilt {
                    return Err(crate::gpu::GpuError::Kernel {
                        kernel: "accel.kdtree",
                        reason: "the kd-tree still ran out of references after 8 \
                                 doublings of its budget"
                            .into(),
                    });
                }
                let (geom, mut rec, r) = self.geometry(ctx, (rs, plan), grow)?;
                recorded = r;
                f.geom = geom;
                restore(&mut rec, &f, pixels);
                pending = Some(rec);
                continue;
            }
            if build_ms.is_none() {
                build_ms = Some(recorded.map(|r| match &f.geom {
                    Traced::Levels(l) => p.ms("levels").unwrap_or(0.0) + l.bottom_ms,
                    Traced::Flat(_) => r.ms(&p),
                }));
            }
            if counters.read()?[counter::OVERFLOW] != 0 {
                // A wave's queue overflowed: undo the sample, redo it with smaller waves.
                if wave_pixels == 1 {
                    return Err(crate::gpu::GpuError::Kernel {
                        kernel: "render",
                        reason: format!(
                            "one pixel's bounce tree needs more than {} rays at one depth: \
                             lower settings.max_depth",
                            plan.queue_capacity
                        ),
                    });
                }
                wave_pixels = (wave_pixels / 4).max(1);
                redone_samples += 1;
                let mut rec = Recorder::new(ctx)?;
                restore(&mut rec, &f, pixels);
                pending = Some(rec);
                continue;
            }
            profile.append(p);
            sample += 1;
            progress(sample);
        }
        let mut rec = Recorder::new(ctx)?;
        self.record_tonemap(&mut rec, &f, plan);
        profile.append(rec.submit_and_wait()?);
        let radiance = mean_radiance(&f.accum.download()?, plan.spp);
        let rgba = bytemuck::cast_slice(&f.pixels.download()?).to_vec();
        let c = f.counters.download()?;
        Ok(GpuRender {
            radiance,
            rgba,
            counts: RayCounts::from_counters(&c),
            profile,
            redone_samples,
            build_ms: build_ms.flatten(),
            traffic: ctx.traffic() - start,
            build_attempts: grow + 1,
            readback_before_trace,
        })
    }

    /// Records one sample of every pixel, wave by wave; with `save`, after saving `accum`
    /// and `counters` (restored by [`restore`] when a wave's queue overflows).
    fn record_sample(
        &self,
        rec: &mut Recorder,
        f: &Frame,
        plan: &Plan,
        wave_pixels: u32,
        sample: u32,
        save: bool,
    ) {
        if save {
            let pixels = plan.width as usize * plan.height as usize;
            rec.compute_to_transfer();
            rec.copy(&f.accum, &f.accum_before, pixels);
            rec.copy(&f.counters, &f.counters_before, counter::WORDS);
            rec.transfer_to_compute();
        }
        rec.scope("render.sample", |rec| {
            for wave in 0..plan.waves_of(wave_pixels) {
                self.record_wave(rec, f, plan, wave_pixels, sample, wave);
            }
        });
    }

    /// Records the tone map of the mean of `plan.spp` samples into `pixels`, ending with a
    /// compute → transfer barrier.
    fn record_tonemap(&self, rec: &mut Recorder, f: &Frame, plan: &Plan) {
        let pixels = plan.width * plan.height;
        rec.compute_to_compute();
        rec.scope("render.tonemap", |rec| {
            let groups = rec.groups_1d(pixels as u64, WG);
            let push = TonemapPush {
                n: pixels,
                inv_spp: 1.0 / plan.spp as f32,
            };
            rec.dispatch(&self.k.tonemap, groups, &[&f.accum, &f.pixels], &push);
        });
        rec.compute_to_transfer();
    }

    fn record_wave(
        &self,
        rec: &mut Recorder,
        f: &Frame,
        plan: &Plan,
        wave_pixels: u32,
        sample: u32,
        wave: u32,
    ) {
        let k = &self.k;
        let total = plan.width as u64 * plan.height as u64;
        let first = wave as u64 * wave_pixels as u64;
        let pixels = (total - first).min(wave_pixels as u64) as u32;
        rec.compute_to_compute();
        rec.scope("render.camera", |rec| {
            let push = CameraPush {
                first_pixel: first as u32,
                pixels,
                sample,
                wg: WG,
            };
            let groups = rec.groups_1d(pixels as u64, WG);
            rec.dispatch(
                &k.camera,
                groups,
                &[&f.params, &f.queue, &f.counters],
                &push,
            );
        });
        rec.compute_to_indirect();
        let args_queue = (counter::ARGS_QUEUE * 4) as u64;
        let args_shadow = (counter::ARGS_SHADOW * 4) as u64;
        let mut capacity = pixels as usize;
        for depth in 0..=plan.max_depth {
            let spawn = plan.bounces && depth < plan.max_depth;
            rec.scope("render.extend", |rec| match &f.geom {
                Traced::Flat(g) => {
                    let b = around_geometry(&[&f.queue, &f.hits, &f.counters], &g.bindings(), &[]);
                    rec.dispatch_indirect(&k.extend, &f.counters, args_queue, &b, &());
                }
                Traced::Levels(l) => self.record_levels(rec, f, l, false),
            });
            if spawn {
                rec.compute_to_transfer();
                rec.fill(&f.flags, 0);
                rec.transfer_to_compute();
            } else {
                rec.compute_to_compute();
            }
            rec.scope("render.shade", |rec| {
                // shade reads the primitives, not the tree (bindings 3 and 4 are unused)
                let kernel = match &f.geom {
                    Traced::Flat(_) => &k.shade,
                    Traced::Levels(_) => k.shade_levels.as_ref().expect("a plan over two levels"),
                };
                let per_primitive: [&dyn BufferArg; 2] = [&f.prim_material, &f.tri_normals];
                let per_primitive = match &f.geom {
                    Traced::Flat(_) => &per_primitive[..],
                    // (read at the levels' addresses)
                    Traced::Levels(_) => &[],
                };
                let b = around_geometry(
                    &[&f.queue, &f.hits, &f.counters],
                    &f.geom.shading_bindings(),
                    &[
                        &[&f.params as &dyn BufferArg, &f.materials, &f.lights][..],
                        per_primitive,
                        &[
                            &f.radiance as &dyn BufferArg,
                            &f.shadows,
                            &f.children,
                            &f.flags,
                        ],
                    ]
                    .concat(),
                );
                rec.dispatch_indirect(kernel, &f.counters, args_queue, &b, &());
            });
            rec.compute_to_compute();
            if plan.shadow_slots > 0 {
                rec.scope("render.shadow", |rec| match &f.geom {
                    Traced::Flat(g) => {
                        let head: [&dyn BufferArg; 3] = [&f.shadows, &f.params, &f.counters];
                        let b = around_geometry(&head, &g.bindings(), &[&f.queue]);
                        rec.dispatch_indirect(&k.shadow, &f.counters, args_shadow, &b, &());
                    }
                    Traced::Levels(l) => self.record_levels(rec, f, l, true),
                });
                rec.compute_to_compute();
            }
            rec.scope("render.accumulate", |rec| {
                let b: [&dyn BufferArg; 6] = [
                    &f.queue,
                    &f.radiance,
                    &f.shadows,
                    &f.params,
                    &f.counters,
                    &f.accum,
                ];
                rec.dispatch_indirect(&k.accumulate, &f.counters, args_queue, &b, &());
            });
            if !spawn {
                continue;
            }
            rec.compute_to_compute();
            let slots = 2 * capacity.min(plan.queue_capacity);
            rec.scope("render.compact", |rec| {
                // two child slots per live ray: the work follows the live count
                let live = GpuCount {
                    counts: &f.counters,
                    index: counter::QUEUE as u32,
                    mul: 2,
                    div: 1,
                };
                self.compact.record_counted(
                    rec,
                    &f.flags,
                    slots,
                    live,
                    &[&f.iota],
                    &[&f.live],
                    &f.compact,
                );
                rec.compute_to_compute();
                let b: [&dyn BufferArg; 3] = [f.compact.count(), &f.params, &f.counters];
                let push = [WG, plan.queue_capacity as u32];
                rec.dispatch(&k.advance, [1, 1, 1], &b, &push);
            });
            rec.compute_to_indirect();
            rec.scope("render.gather", |rec| {
                let b: [&dyn BufferArg; 4] = [&f.children, &f.live, &f.counters, &f.queue];
                rec.dispatch_indirect(&k.gather, &f.counters, args_queue, &b, &());
            });
            rec.compute_to_indirect();
            capacity = capacity.saturating_mul(plan.branching as usize);
        }
    }

    /// Records the extend pass (closest hits) or, with `shadow`, the shadow pass (occlusion)
    /// over two levels: `render.instances`, as many invocations as the flat kernels.
    fn record_levels(&self, rec: &mut Recorder, f: &Frame, l: &Levels, shadow: bool) {
        if let Top::Driver {
            geom,
            starts,
            n_starts,
            ..
        } = &l.top
        {
            return self.record_driver_levels(rec, f, l, (geom, starts, *n_starts), shadow);
        }
        let kernel = self.k.instances.as_ref().expect("a plan over two levels");
        let b: [&dyn BufferArg; 6] = [
            &f.queue,
            &f.hits,
            &f.counters,
            &f.shadows,
            &f.params,
            &l.hit_instance,
        ];
        let push = InstancesPush {
            shadow: shadow as u32,
            pad: 0,
            handle: l.handle(),
        };
        let args = match shadow {
            true => counter::ARGS_SHADOW,
            false => counter::ARGS_QUEUE,
        };
        rec.dispatch_indirect(kernel, &f.counters, (args * 4) as u64, &b, &push);
    }
}

impl Renderer {
    /// [`Renderer::record_levels`] over the driver's levels: the flat kernels' ray query
    /// walks its TLAS, then (extend) `render.driver_hits` maps each hit to its instance and
    /// the primitive in that instance's bottom level.
    fn record_driver_levels(
        &self,
        rec: &mut Recorder,
        f: &Frame,
        l: &Levels,
        (geom, starts, n_starts): (&GpuGeometry, &Buffer<[u32; 4]>, u32),
        shadow: bool,
    ) {
        let k = &self.k;
        if shadow {
            let head: [&dyn BufferArg; 3] = [&f.shadows, &f.params, &f.counters];
            let b = around_geometry(&head, &geom.bindings(), &[&f.queue]);
            rec.dispatch_indirect(
                &k.shadow,
                &f.counters,
                (counter::ARGS_SHADOW * 4) as u64,
                &b,
                &(),
            );
            return;
        }
        let args = (counter::ARGS_QUEUE * 4) as u64;
        let b = around_geometry(&[&f.queue, &f.hits, &f.counters], &geom.bindings(), &[]);
        rec.dispatch_indirect(&k.extend, &f.counters, args, &b, &());
        rec.compute_to_compute();
        let kernel = k
            .driver_hits
            .as_ref()
            .expect("a plan over the driver's levels");
        let b: [&dyn BufferArg; 4] = [&f.hits, &f.counters, starts, &l.hit_instance];
        rec.dispatch_indirect(kernel, &f.counters, args, &b, &n_starts);
    }
}

/// The extend and shadow passes over two levels, for the options the device runs
/// (`render.instances`).
fn instances_kernel(ctx: &Context, opt: &TraceOptions, bitstack: bool) -> Result<Arc<Kernel>> {
    let variants = [
        &kernels::RENDER_INSTANCES_MOLLER,
        &kernels::RENDER_INSTANCES_EXACT,
        &kernels::RENDER_INSTANCES_FLOAT,
        &kernels::RENDER_INSTANCES_BITSTACK_MOLLER,
        &kernels::RENDER_INSTANCES_BITSTACK_EXACT,
        &kernels::RENDER_INSTANCES_BITSTACK_FLOAT,
    ];
    crate::trace::instanced::library_kernel(ctx, opt, bitstack, variants, WG)
}
