//! The wavefront renderer on the GPU: per sample, per wave of pixels, camera rays, then per
//! bounce extend (closest hit) → shade → shadow (any hit) → accumulate → compact the live
//! children (the compaction primitive) → gather, all recorded into one command buffer per
//! sample with ray counts and dispatch sizes kept on the GPU (indirect dispatch).

use std::sync::Arc;

use crate::gpu::{kernels, Buffer, BufferArg, Context, Kernel, Profile, Recorder, Result, Spec};
use crate::prims::compact::{Compact, CompactScratch};
use crate::prims::scan::GpuCount;
use crate::prims::PrimConfig;
use crate::trace::gpu::{effective_options, traversal_spec, GpuGeometry};
use crate::trace::{Hit, Query, TraceOptions};

use super::plan::Plan;
use super::types::{counter, PathRay, ShadowRay};
use super::{RayCounts, RenderAccel, RenderScene};

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
}

/// Kernels specialised for one plan.
pub struct Renderer {
    k: Kernels,
    compact: Compact,
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
struct TonemapPush {
    n: u32,
    inv_spp: f32,
}

/// Device buffers of one render.
struct Frame {
    params: Buffer<super::types::RenderParams>,
    geom: GpuGeometry,
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
    pub counts: RayCounts,
    pub profile: Profile,
    /// Samples redone with smaller waves after a queue overflow.
    pub redone_samples: u32,
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
    pub fn new(ctx: &Context, plan: &Plan, trace: &TraceOptions) -> Result<Self> {
        let opt = effective_options(ctx, trace);
        let closest = traversal_spec(&TraceOptions {
            query: Query::Closest,
            ..opt
        })
        .u32(20, plan.accel.spec())
        .workgroup(WG);
        let any = traversal_spec(&TraceOptions {
            query: Query::Any,
            ..opt
        })
        .u32(20, plan.accel.spec())
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
        let (extend, shadow) = if opt.exact {
            (&kernels::RENDER_EXTEND_EXACT, &kernels::RENDER_SHADOW_EXACT)
        } else {
            (&kernels::RENDER_EXTEND_FLOAT, &kernels::RENDER_SHADOW_FLOAT)
        };
        Ok(Self {
            k: Kernels {
                camera: ctx.kernel(&kernels::RENDER_CAMERA, &camera)?,
                extend: ctx.kernel(extend, &closest)?,
                shade: ctx.kernel(&kernels::RENDER_SHADE, &shade)?,
                shadow: ctx.kernel(shadow, &any)?,
                accumulate: ctx.kernel(&kernels::RENDER_ACCUMULATE, &plain)?,
                advance: ctx.kernel(&kernels::RENDER_ADVANCE, &Spec::new())?,
                gather: ctx.kernel(&kernels::RENDER_GATHER, &plain)?,
                tonemap: ctx.kernel(&kernels::RENDER_TONEMAP, &plain)?,
            },
            compact: Compact::new(ctx, PrimConfig::default_for(ctx))?,
        })
    }

    fn frame(&self, ctx: &Context, rs: &RenderScene, plan: &Plan) -> Result<Frame> {
        let cap = plan.queue_capacity;
        let slots = plan.shadow_slots as usize;
        let pixels = plan.width as usize * plan.height as usize;
        let iota: Vec<u32> = (0..2 * cap as u32).collect();
        Ok(Frame {
            params: Buffer::from_slice(ctx, "render.params", &[rs.params])?,
            geom: match &rs.accel {
                RenderAccel::KdTree(tree) => GpuGeometry::upload(ctx, &rs.geometry, tree)?,
                RenderAccel::Bvh(bvh) => GpuGeometry::upload_bvh(ctx, &rs.geometry, bvh)?,
            },
            materials: Buffer::from_slice(ctx, "render.materials", &rs.materials)?,
            lights: Buffer::from_slice(ctx, "render.lights", &rs.lights)?,
            prim_material: Buffer::from_slice(ctx, "render.prim_material", &rs.prim_material)?,
            tri_normals: Buffer::from_slice(ctx, "render.tri_normals", &rs.tri_normals)?,
            queue: Buffer::new(ctx, "render.queue", cap)?,
            hits: Buffer::new(ctx, "render.hits", cap)?,
            radiance: Buffer::new(ctx, "render.radiance", cap)?,
            shadows: Buffer::new(ctx, "render.shadows", (cap * slots).max(1))?,
            children: Buffer::new(ctx, "render.children", 2 * cap)?,
            flags: Buffer::zeroed(ctx, "render.flags", 2 * cap)?,
            iota: Buffer::from_slice(ctx, "render.iota", &iota)?,
            live: Buffer::new(ctx, "render.live", 2 * cap)?,
            compact: self.compact.scratch(ctx, 2 * cap)?,
            counters: Buffer::zeroed(ctx, "render.counters", counter::WORDS)?,
            accum: Buffer::zeroed(ctx, "render.accum", pixels)?,
            accum_before: Buffer::new(ctx, "render.accum_before", pixels)?,
            counters_before: Buffer::new(ctx, "render.counters_before", counter::WORDS)?,
            pixels: Buffer::new(ctx, "render.pixels", pixels)?,
        })
    }

    /// Renders `plan.spp` samples; `progress(done)` is called after each sample.
    pub fn render(
        &self,
        ctx: &Context,
        rs: &RenderScene,
        plan: &Plan,
        mut progress: impl FnMut(u32),
    ) -> Result<GpuRender> {
        let f = self.frame(ctx, rs, plan)?;
        let mut profile = Profile::default();
        let pixels = plan.width * plan.height;
        let mut wave_pixels = plan.wave_pixels;
        let mut redone_samples = 0;
        let mut sample = 0;
        while sample < plan.spp {
            let mut rec = Recorder::new(ctx)?;
            rec.compute_to_transfer();
            rec.copy(&f.accum, &f.accum_before, pixels as usize);
            rec.copy(&f.counters, &f.counters_before, counter::WORDS);
            rec.transfer_to_compute();
            rec.scope("render.sample", |rec| {
                for wave in 0..plan.waves_of(wave_pixels) {
                    self.record_wave(rec, &f, plan, wave_pixels, sample, wave);
                }
            });
            rec.compute_to_transfer();
            rec.compute_to_host();
            let p = rec.submit_and_wait()?;
            if f.counters.download()?[counter::OVERFLOW] != 0 {
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
                rec.compute_to_transfer();
                rec.copy(&f.accum_before, &f.accum, pixels as usize);
                rec.copy(&f.counters_before, &f.counters, counter::WORDS);
                rec.transfer_to_host();
                rec.submit_and_wait()?;
                continue;
            }
            profile.append(p);
            sample += 1;
            progress(sample);
        }
        let mut rec = Recorder::new(ctx)?;
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
        profile.append(rec.submit_and_wait()?);
        let inv = 1.0 / plan.spp as f32;
        let radiance = f
            .accum
            .download()?
            .iter()
            .map(|a| [a[0] * inv, a[1] * inv, a[2] * inv])
            .collect();
        let rgba = bytemuck::cast_slice(&f.pixels.download()?).to_vec();
        let c = f.counters.download()?;
        Ok(GpuRender {
            radiance,
            rgba,
            counts: RayCounts::from_counters(&c),
            profile,
            redone_samples,
        })
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
        let g = f.geom.bindings();
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
            rec.scope("render.extend", |rec| {
                let b = around_geometry(&[&f.queue, &f.hits, &f.counters], &g, &[]);
                rec.dispatch_indirect(&k.extend, &f.counters, args_queue, &b, &());
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
                let b = around_geometry(
                    &[&f.queue, &f.hits, &f.counters],
                    &g[2..],
                    &[
                        &f.params,
                        &f.materials,
                        &f.lights,
                        &f.prim_material,
                        &f.tri_normals,
                        &f.radiance,
                        &f.shadows,
                        &f.children,
                        &f.flags,
                    ],
                );
                rec.dispatch_indirect(&k.shade, &f.counters, args_queue, &b, &());
            });
            rec.compute_to_compute();
            if plan.shadow_slots > 0 {
                rec.scope("render.shadow", |rec| {
                    let b = around_geometry(&[&f.shadows, &f.params, &f.counters], &g, &[&f.queue]);
                    rec.dispatch_indirect(&k.shadow, &f.counters, args_shadow, &b, &());
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
}
