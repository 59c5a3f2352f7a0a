//! Frames of an animation on the device. The renderer's buffers, the primitives
//! and the structure are made once, with the first frame; every later frame writes its moved
//! primitives where they lie, rebuilds or refits the structure, and renders every sample and
//! the tone map after it: one submission per frame, with nothing read back but the image (and
//! the ray counters, which say whether a wave overflowed).

use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind, AccelScratch, DevicePrimitives};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::gpu::{Buffer, Context, GpuError, Profile, Recorder, Result, Traffic};
use crate::render::types::counter;
use crate::render::{Plan, RayCounts, RenderScene};

use super::levels::{Levels, Traced};
use super::{Frame, Renderer};

/// How the structure follows the primitives from one frame to the next.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Update {
    /// Built anew every frame (any kind).
    #[default]
    Rebuild,
    /// Built once, then its boxes recomputed over the same topology (BVHs and the driver's:
    /// `VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR`).
    Refit,
}

impl Update {
    /// `rebuild` or `refit`, as reports print it.
    pub fn name(self) -> &'static str {
        match self {
            Update::Rebuild => "rebuild",
            Update::Refit => "refit",
        }
    }
}

/// One rendered frame.
pub struct FrameImage {
    /// 8-bit sRGB RGBA, row-major from the top-left.
    pub rgba: Vec<u8>,
    /// Mean radiance per pixel (linear), row-major from the top-left, where the loop reads
    /// it back ([`FrameLoop::with_radiance`]: EXR and PFM frames).
    pub radiance: Option<Vec<[f32; 3]>>,
    /// Rays traced per kind in this frame.
    pub counts: RayCounts,
    /// GPU timestamps of the frame's submission.
    pub profile: Profile,
    /// GPU ms of the structure's build or refit (a host builder's wall ms for the SAH BVH's
    /// builds).
    pub update_ms: f64,
    /// Whether this frame built the structure (the first frame always does).
    pub built: bool,
    /// GPU ms of the samples and the tone map.
    pub render_ms: f64,
    /// Submissions and read-backs of this frame (1 and the image, unless it was redone).
    pub traffic: Traffic,
    /// Times the frame was recorded again: a wave's queue overflowed (smaller waves from
    /// then on) or a kd-tree ran out of references (twice the budget from then on).
    pub redone: u32,
}

/// What stays on the device from frame to frame.
struct State {
    f: Frame,
    /// The flat structure's build and refit scratch (none over two levels).
    scratch: Option<AccelScratch>,
    refit_scratch: Option<Buffer<u32>>,
}

/// Renders the frames of one animation with one plan.
pub struct FrameLoop<'r> {
    renderer: &'r Renderer,
    builder: AccelBuilder,
    update: Update,
    state: Option<State>,
    wave_pixels: u32,
    grow: u32,
    radiance: bool,
}

impl<'r> FrameLoop<'r> {
    /// `renderer` must have been made for `plan`, whose structure is `choice`. A kd-tree
    /// cannot be refit (its split planes are fixed): that is an error.
    pub fn new(
        ctx: &Context,
        renderer: &'r Renderer,
        plan: &Plan,
        choice: AccelChoice,
        update: Update,
    ) -> Result<Self> {
        if update == Update::Refit && choice.kind == AccelKind::KdTree && plan.levels < 2 {
            return Err(GpuError::Kernel {
                kernel: "accel.refit",
                reason: "a kd-tree cannot be refit (its split planes are fixed): \
                         use --update rebuild"
                    .into(),
            });
        }
        let mut builder = AccelBuilder::for_choice(ctx, choice)?;
        builder = builder.with_allow_update(update == Update::Refit);
        Ok(Self {
            renderer,
            builder,
            update,
            state: None,
            wave_pixels: plan.wave_pixels,
            grow: 0,
            radiance: false,
        })
    }

    /// Also reads back each frame's linear radiance (16 bytes a pixel more), for float
    /// frame files.
    pub fn with_radiance(mut self, on: bool) -> Self {
        self.radiance = on;
        self
    }

    /// Builds the structure over `rs` without rendering: the tree later frames refit. A
    /// range of an animation that starts past frame 0 builds over frame 0 first, so that
    /// every frame's tree is frame 0's refit to it, whichever range renders the frame.
    pub fn prepare(&mut self, ctx: &Context, rs: &RenderScene, plan: &Plan) -> Result<()> {
        self.state = None;
        let mut rec = Recorder::new(ctx)?;
        self.record_update(&mut rec, rs, plan)?;
        rec.submit_and_wait()?;
        Ok(())
    }

    /// The structure as it is now, read back (tools and reports; `None` before the first
    /// frame, and over two levels). The driver's is opaque: an error.
    pub fn download(&self) -> Result<Option<crate::accel::host::HostStructure>> {
        self.state
            .as_ref()
            .and_then(|st| st.f.geom.flat())
            .map(|g| g.accel.download())
            .transpose()
    }

    /// Renders `rs` (the scene at this frame's time, flattened for `plan`): the same
    /// primitives as every other frame of the loop, moved.
    pub fn render(&mut self, ctx: &Context, rs: &RenderScene, plan: &Plan) -> Result<FrameImage> {
        let start = ctx.traffic();
        let mut redone = 0;
        loop {
            let mut rec = Recorder::new(ctx)?;
            let (built, host_ms, bottoms) = self.record_update(&mut rec, rs, plan)?;
            let st = self.state.as_ref().expect("recorded");
            for sample in 0..plan.spp {
                self.renderer
                    .record_sample(&mut rec, &st.f, plan, self.wave_pixels, sample, false);
            }
            self.renderer.record_tonemap(&mut rec, &st.f, plan);
            // (a flat kd-tree is built every frame; bottom levels with the first)
            let kd_reports = match (st.f.geom.flat(), bottoms) {
                (None, None) => Vec::new(),
                _ => st.f.geom.record_read_built(&mut rec)?,
            };
            let counters = rec.read_back(&st.f.counters)?;
            let pixels = rec.read_back(&st.f.pixels)?;
            let accum = match self.radiance {
                true => Some(rec.read_back(&st.f.accum)?),
                false => None,
            };
            rec.transfer_to_host();
            let profile = rec.submit_and_wait()?;
            if Traced::kd_overflow(kd_reports)? {
                // Every ray of the frame missed: build again with twice the budget.
                self.grow += 1;
                if self.grow > 8 {
                    return Err(GpuError::Kernel {
                        kernel: "accel.kdtree",
                        reason: "the kd-tree still ran out of references after 8 \
                                 doublings of its budget"
                            .into(),
                    });
                }
                self.state = None;
                redone += 1;
                continue;
            }
            let counters = counters.read()?;
            if counters[counter::OVERFLOW] != 0 {
                if self.wave_pixels == 1 {
                    return Err(GpuError::Kernel {
                        kernel: "render",
                        reason: format!(
                            "one pixel's bounce tree needs more than {} rays at one depth: \
                             lower settings.max_depth",
                            plan.queue_capacity
                        ),
                    });
                }
                self.wave_pixels = (self.wave_pixels / 4).max(1);
                redone += 1;
                continue;
            }
            let scope = |name: &str| profile.ms(name).unwrap_or(0.0);
            let update_ms = match st.f.geom {
                Traced::Levels(_) => scope("levels") + bottoms.unwrap_or(0.0),
                Traced::Flat(_) => host_ms.unwrap_or_else(|| scope("build") + scope("update")),
            };
            let radiance = match accum {
                Some(a) => Some(super::mean_radiance(&a.read()?, plan.spp)),
                None => None,
            };
            return Ok(FrameImage {
                rgba: bytemuck::cast_slice(&pixels.read()?).to_vec(),
                radiance,
                counts: RayCounts::from_counters(&counters),
                update_ms,
                built,
                render_ms: scope("render.sample") + scope("render.tonemap"),
                profile,
                traffic: ctx.traffic() - start,
                redone,
            });
        }
    }

    /// Records what brings the device to this frame: the first time (or after a kd-tree
    /// outgrew its budget) the upload of everything and the build (two levels: the bottom
    /// levels' and the top level's); later the moved primitives, the frame's constants and a
    /// rebuild or refit (two levels: the moved instances and the top level only). Returns whether it built,
    /// a host builder's milliseconds and, where it built bottom levels, their host
    /// builder's milliseconds.
    fn record_update(
        &mut self,
        rec: &mut Recorder,
        rs: &RenderScene,
        plan: &Plan,
    ) -> Result<(bool, Option<f64>, Option<f64>)> {
        let b = &self.builder;
        let Some(st) = self.state.as_mut() else {
            let allow_update = self.update == Update::Refit;
            let (geom, scratch, refit_scratch, host_ms, bottom_ms) = match &rs.levels {
                Some(rl) => {
                    let sizes = (self.grow, plan.queue_capacity);
                    let shading = (rl, &rs.prim_material[..], &rs.tri_normals[..]);
                    let levels =
                        Levels::record_build(rec, plan.accel, shading, sizes, allow_update)?;
                    let ms = Some(levels.bottom_ms);
                    (Traced::Levels(levels), None, None, None, ms)
                }
                None => {
                    let prims = DevicePrimitives::record_upload(rec, &rs.geometry)?;
                    let (mut accel, scratch) = b.create(rec.context(), prims.count(), self.grow)?;
                    let recorded = rec.scope("build", |rec| {
                        b.record_build(rec, &mut accel, &prims, &rs.geometry, &scratch)
                    })?;
                    let refit_scratch = b.update_scratch(rec.context(), prims.count())?;
                    let geom = GpuGeometry {
                        prims,
                        accel,
                        device_input: None,
                        life: Default::default(),
                    };
                    let host_ms = recorded.host_ms;
                    (
                        Traced::Flat(geom),
                        Some(scratch),
                        refit_scratch,
                        host_ms,
                        None,
                    )
                }
            };
            let f = self.renderer.frame(rec, rs, plan, geom)?;
            self.state = Some(State {
                f,
                scratch,
                refit_scratch,
            });
            return Ok((true, host_ms, bottom_ms));
        };
        self.renderer.record_reset(rec, &st.f, rs)?;
        let g = &rs.geometry;
        let geom = match &mut st.f.geom {
            Traced::Levels(levels) => {
                let rl = rs.levels.as_ref().ok_or_else(|| GpuError::Kernel {
                    kernel: "render",
                    reason: "a frame of a two-level animation came flat".into(),
                })?;
                levels.record_update(rec, rl, self.update)?;
                return Ok((self.update == Update::Rebuild, None, None));
            }
            Traced::Flat(geom) => geom,
        };
        let prims = &geom.prims;
        prims.record_update(rec, g)?;
        match self.update {
            Update::Rebuild => {
                let accel = &mut geom.accel;
                let scratch = st.scratch.as_ref().expect("build scratch");
                let recorded =
                    rec.scope("build", |rec| b.record_build(rec, accel, prims, g, scratch))?;
                Ok((true, recorded.host_ms, None))
            }
            Update::Refit => {
                let scratch = st.refit_scratch.as_ref().expect("refit scratch");
                let accel = &mut geom.accel;
                rec.scope("update", |rec| {
                    b.record_refit_parts(rec, accel, prims, scratch)
                })?;
                Ok((false, None, None))
            }
        }
    }
}
