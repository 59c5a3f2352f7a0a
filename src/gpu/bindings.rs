//! Where a recording's descriptor sets and texel views come from: pools a recorder grows
//! and destroys with itself, or a [`BindingCache`] that an embedding renderer prepares once
//! and every later recording binds from, creating nothing.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use ash::vk;

use super::buffer::BufferArg;
use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::recorder::Recorder;

const SETS_PER_POOL: u32 = 256;
const BUFFERS_PER_POOL: u32 = SETS_PER_POOL * 8;

/// A range bound to a kernel: buffer, offset, bytes.
pub(crate) type RangeKey = (vk::Buffer, u64, u64);

/// Descriptor pools that grow by one pool of [`SETS_PER_POOL`] sets when the last is full.
#[derive(Default)]
pub(crate) struct SetPools {
    pools: Vec<vk::DescriptorPool>,
}

impl SetPools {
    /// A fresh set of `layout`.
    pub(crate) fn allocate(
        &mut self,
        ctx: &Context,
        layout: vk::DescriptorSetLayout,
    ) -> Result<vk::DescriptorSet> {
        let device = &ctx.inner.device;
        let layouts = [layout];
        if let Some(&pool) = self.pools.last() {
            let info = vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(pool)
                .set_layouts(&layouts);
            // SAFETY: the pool is ours and not used by another thread (its owner is
            // `&mut`, or behind the cache's mutex).
            if let Ok(sets) = unsafe { device.allocate_descriptor_sets(&info) } {
                ctx.inner.created(1);
                return Ok(sets[0]);
            }
        }
        let sizes = [
            vk::DescriptorPoolSize {
                ty: vk::DescriptorType::STORAGE_BUFFER,
                descriptor_count: BUFFERS_PER_POOL,
            },
            vk::DescriptorPoolSize {
                ty: vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
                descriptor_count: SETS_PER_POOL * 2,
            },
        ];
        let pool_info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(SETS_PER_POOL)
            .pool_sizes(&sizes);
        // SAFETY: valid device; pools are destroyed by their owner after the work that
        // binds their sets has completed.
        let pool = unsafe { device.create_descriptor_pool(&pool_info, None) }
            .map_err(vk_err("vkCreateDescriptorPool"))?;
        ctx.inner.created(1);
        self.pools.push(pool);
        let info = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(pool)
            .set_layouts(&layouts);
        // SAFETY: a fresh pool sized for far more than one set of at most 10 buffers.
        let sets = unsafe { device.allocate_descriptor_sets(&info) }
            .map_err(vk_err("vkAllocateDescriptorSets"))?;
        ctx.inner.created(1);
        Ok(sets[0])
    }

    /// Forgets the pools without destroying them (their sets may still be in use).
    pub(crate) fn leak(&mut self) {
        self.pools.clear();
    }

    /// # Safety
    /// No pending work binds a set of these pools.
    pub(crate) unsafe fn destroy(&mut self, device: &ash::Device) {
        for pool in self.pools.drain(..) {
            // SAFETY: the caller's contract.
            unsafe { device.destroy_descriptor_pool(pool, None) };
        }
    }
}

/// RGBA32UI views of bound ranges, one per range.
#[derive(Default)]
pub(crate) struct Views {
    views: HashMap<RangeKey, vk::BufferView>,
}

impl Views {
    /// The view of `b`'s range, made on first use.
    pub(crate) fn of(&mut self, ctx: &Context, b: &dyn BufferArg) -> Result<vk::BufferView> {
        let key = (b.raw(), b.offset(), b.range());
        if let Some(&view) = self.views.get(&key) {
            return Ok(view);
        }
        let view = super::buffer::create_texel_view(ctx, b)?;
        self.views.insert(key, view);
        Ok(view)
    }

    /// Forgets the views without destroying them (they may still be in use).
    pub(crate) fn leak(&mut self) {
        self.views.clear();
    }

    /// # Safety
    /// No pending work reads through these views.
    pub(crate) unsafe fn destroy(&mut self, device: &ash::Device) {
        for (_, view) in self.views.drain() {
            // SAFETY: the caller's contract.
            unsafe { device.destroy_buffer_view(view, None) };
        }
    }
}

/// A descriptor set's identity: its layout and the ranges written into it. A cached set is
/// written once and never again, so every command buffer that binds it — pending or not —
/// reads what it was written with.
type SetKey = (vk::DescriptorSetLayout, Vec<RangeKey>);

#[derive(Default)]
struct CacheState {
    pools: SetPools,
    views: Views,
    sets: HashMap<SetKey, vk::DescriptorSet>,
}

pub(crate) struct CacheShared {
    ctx: Context,
    state: Mutex<CacheState>,
}

/// Descriptor sets and texel views made once and bound by every recording that shares the
/// cache ([`Recorder::from_raw_with`]): after [`BindingCache::prepare`] has recorded a
/// frame's calls once, recording the same calls again (the same kernels over the same
/// ranges — a structure rebuilt in place, a trace into the same buffers) creates no Vulkan
/// object (`Traffic::objects_created`). A call over ranges the cache has not seen adds
/// their set to it.
///
/// The cache lives as long as its last clone and the last recording that bound from it
/// (each [`crate::gpu::RecordedWork`] holds it until completed); it destroys its pools and
/// views then. Sharing one across threads and frames in flight is safe: sets are written
/// only when made.
#[derive(Clone)]
pub struct BindingCache {
    pub(crate) shared: Arc<CacheShared>,
}

impl BindingCache {
    /// An empty cache (no Vulkan object is created until a recording needs one).
    pub fn new(ctx: &Context) -> Self {
        Self {
            shared: Arc::new(CacheShared {
                ctx: ctx.clone(),
                state: Mutex::default(),
            }),
        }
    }

    /// Records `frame` once into a command buffer of vkrt's that is never submitted, so that
    /// every kernel it dispatches is compiled and every descriptor set and texel view it
    /// binds is made and kept here. Call it before the first frame with the calls each
    /// frame records (a structure's `record_build_from`, a tracer's `record`, ...). Nothing
    /// executes: the buffers hold what they held. `Err`: what `frame` or the recording
    /// returned.
    pub fn prepare(&self, frame: impl FnOnce(&mut Recorder) -> Result<()>) -> Result<()> {
        let mut rec = Recorder::new_with(&self.shared.ctx, Some(self.clone()))?;
        frame(&mut rec)?;
        rec.check()
        // Dropped unsubmitted: its command buffer and pool go; the cache keeps the rest.
    }

    /// Descriptor sets the cache holds.
    pub fn sets(&self) -> usize {
        super::error::lock(&self.shared.state).sets.len()
    }

    /// The set of `layout` written with `buffers` (texel bindings through views of their
    /// ranges), made and written on first use.
    pub(crate) fn set_for(
        &self,
        layout: vk::DescriptorSetLayout,
        buffers: &[&dyn BufferArg],
        write: impl FnOnce(vk::DescriptorSet, &mut Views) -> Result<()>,
    ) -> Result<vk::DescriptorSet> {
        let key: SetKey = (
            layout,
            buffers
                .iter()
                .map(|b| (b.raw(), b.offset(), b.range()))
                .collect(),
        );
        let ctx = &self.shared.ctx;
        let mut state = super::error::lock(&self.shared.state);
        if let Some(&set) = state.sets.get(&key) {
            return Ok(set);
        }
        let set = state.pools.allocate(ctx, layout)?;
        // A set whose write failed stays unused in its pool.
        write(set, &mut state.views)?;
        state.sets.insert(key, set);
        Ok(set)
    }

    /// Whether this cache serves `ctx`'s device.
    pub(crate) fn serves(&self, ctx: &Context) -> bool {
        Arc::ptr_eq(&self.shared.ctx.inner, &ctx.inner)
    }
}

impl Drop for CacheShared {
    fn drop(&mut self) {
        let state = self
            .state
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let device = &self.ctx.inner.device;
        // SAFETY: the last clone of the cache is gone, and every recording that bound from it
        // held one until its work completed; nothing pending uses these sets and views.
        unsafe {
            state.pools.destroy(device);
            state.views.destroy(device);
        }
    }
}

impl std::fmt::Debug for BindingCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BindingCache")
            .field("sets", &self.sets())
            .finish()
    }
}

/// `Err` for a cache of another device.
pub(crate) fn check_serves(cache: &BindingCache, ctx: &Context) -> Result<()> {
    match cache.serves(ctx) {
        true => Ok(()),
        false => Err(GpuError::Usage {
            call: "Recorder::from_raw_with",
            reason: "the binding cache was made for another context".into(),
        }),
    }
}
