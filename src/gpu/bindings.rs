//! Where a recording's descriptor sets and texel views come from: pools a recorder grows
//! and destroys with itself, or a [`BindingCache`] that an embedding renderer prepares once
//! and every later recording binds from, creating nothing.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, Weak};

use ash::vk;

use super::buffer::{BufferArg, BufferId};
use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::recorder::Recorder;

const SETS_PER_POOL: u32 = 256;
const BUFFERS_PER_POOL: u32 = SETS_PER_POOL * 8;

/// A range bound to a kernel: buffer, offset, bytes.
pub(crate) type RangeKey = (BufferId, u64, u64);

/// The key of `b`'s range.
fn range_key(b: &dyn BufferArg) -> RangeKey {
    (b.id(), b.offset(), b.range())
}

/// Descriptor pools that grow by one pool of [`SETS_PER_POOL`] sets when the last is full.
#[derive(Default)]
pub(crate) struct SetPools {
    pools: Vec<vk::DescriptorPool>,
    /// Whether sets can be freed one by one (a cache's pools, whose evicted sets' slots
    /// serve later sets).
    freeable: bool,
}

impl SetPools {
    /// A fresh set of `layout`, and the pool it is from.
    pub(crate) fn allocate(
        &mut self,
        ctx: &Context,
        layout: vk::DescriptorSetLayout,
    ) -> Result<(vk::DescriptorPool, vk::DescriptorSet)> {
        let device = &ctx.inner.device;
        let layouts = [layout];
        // The newest pool first; a cache's older pools may have freed slots.
        let tried = if self.freeable { self.pools.len() } else { 1 };
        for &pool in self.pools.iter().rev().take(tried) {
            let info = vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(pool)
                .set_layouts(&layouts);
            // SAFETY: the pool is ours and not used by another thread (its owner is
            // `&mut`, or behind the cache's mutex).
            if let Ok(sets) = unsafe { device.allocate_descriptor_sets(&info) } {
                ctx.inner.created(1);
                return Ok((pool, sets[0]));
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
        let flags = match self.freeable {
            true => vk::DescriptorPoolCreateFlags::FREE_DESCRIPTOR_SET,
            false => vk::DescriptorPoolCreateFlags::empty(),
        };
        let pool_info = vk::DescriptorPoolCreateInfo::default()
            .flags(flags)
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
        Ok((pool, sets[0]))
    }

    /// Returns `set` to `pool` (one of these freeable pools).
    ///
    /// # Safety
    /// No pending work binds `set`.
    unsafe fn free(
        &mut self,
        device: &ash::Device,
        pool: vk::DescriptorPool,
        set: vk::DescriptorSet,
    ) {
        debug_assert!(self.freeable && self.pools.contains(&pool));
        // SAFETY: the pool was created with FREE_DESCRIPTOR_SET and `set` is its; the
        // caller's contract. (The call returns VK_SUCCESS only.)
        let _ = unsafe { device.free_descriptor_sets(pool, &[set]) };
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
        let key = range_key(b);
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

    /// Destroys the views of `id`'s ranges; how many.
    ///
    /// # Safety
    /// No pending work reads through them.
    unsafe fn evict(&mut self, device: &ash::Device, id: BufferId) -> usize {
        let before = self.views.len();
        self.views.retain(|key, view| {
            let keep = key.0 != id;
            if !keep {
                // SAFETY: the caller's contract.
                unsafe { device.destroy_buffer_view(*view, None) };
            }
            keep
        });
        before - self.views.len()
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
    sets: HashMap<SetKey, (vk::DescriptorPool, vk::DescriptorSet)>,
    /// Whether a miss outside `prepare` is an error ([`BindingCache::seal`]).
    sealed: bool,
    /// Sets and views evicted so far.
    evicted: u64,
}

impl CacheState {
    /// Frees the sets and views that bind a range of `id`.
    ///
    /// # Safety
    /// No pending work binds a range of `id` through this cache.
    unsafe fn evict(&mut self, device: &ash::Device, id: BufferId) {
        let mut freed = Vec::new();
        self.sets.retain(|key, &mut (pool, set)| {
            let keep = key.1.iter().all(|r| r.0 != id);
            if !keep {
                freed.push((pool, set));
            }
            keep
        });
        for &(pool, set) in &freed {
            // SAFETY: the caller's contract: no pending work binds a set with `id`'s range.
            unsafe { self.pools.free(device, pool, set) };
        }
        // SAFETY: as above, for the views of its ranges.
        let views = unsafe { self.views.evict(device, id) };
        self.evicted += (freed.len() + views) as u64;
    }
}

pub(crate) struct CacheShared {
    ctx: crate::gpu::teardown::Held,
    state: Mutex<CacheState>,
}

/// Descriptor sets and texel views made once and bound by every recording that shares the
/// cache ([`Recorder::from_raw_with`]): after [`BindingCache::prepare`] has recorded a
/// frame's calls once, recording the same calls again (the same kernels over the same
/// ranges — a structure rebuilt in place, a trace into the same buffers) creates no Vulkan
/// object (`Traffic::objects_created`). A call over ranges the cache has not seen adds
/// their set to it.
///
/// Entries are keyed by buffer identity, not by Vulkan handle (which a driver reuses once a
/// buffer is destroyed): a vkrt [`Buffer`](crate::gpu::Buffer)'s sets and views are freed
/// when it drops, and a caller's buffer's when [`forget`](Self::forget) is told of it before
/// it is destroyed ([`RawBuffer::new`](crate::gpu::RawBuffer::new)'s contract). A streaming
/// renderer's cache therefore holds the sets of its live buffers only.
///
/// After [`seal`](Self::seal), a recording that would need a set the cache lacks fails
/// with [`GpuError::CacheMiss`] instead of creating one in the frame.
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
        let state = CacheState {
            pools: SetPools {
                freeable: true,
                ..SetPools::default()
            },
            ..CacheState::default()
        };
        let shared = Arc::new(CacheShared {
            ctx: crate::gpu::teardown::Held::new(ctx, crate::gpu::teardown::Holder::BindingCache),
            state: Mutex::new(state),
        });
        ctx.inner.caches.register(Arc::downgrade(&shared));
        Self { shared }
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

    /// Descriptor sets and texel views freed so far because a buffer they bind dropped or
    /// was forgotten.
    pub fn evicted(&self) -> u64 {
        super::error::lock(&self.shared.state).evicted
    }

    /// From now on a recording that needs a descriptor set the cache lacks fails with
    /// [`GpuError::CacheMiss`] (its command buffer is then the caller's to reset) rather than
    /// creating one; [`prepare`](Self::prepare) still adds. Call it after preparing, so that
    /// a frame recording over a buffer it was not prepared for is an error the renderer sees,
    /// not an object created in its frame.
    pub fn seal(&self) {
        super::error::lock(&self.shared.state).sealed = true;
    }

    /// Frees every set and view the cache holds for ranges of the caller's `buffer`. Call
    /// it before destroying a buffer that was bound through [`RawBuffer`](crate::gpu::RawBuffer)s
    /// (vkrt's own [`Buffer`](crate::gpu::Buffer)s are forgotten when they drop).
    ///
    /// # Safety
    /// No pending work binds a range of `buffer` through this cache: the condition under
    /// which `buffer` may be destroyed.
    pub unsafe fn forget(&self, buffer: vk::Buffer) {
        let mut state = super::error::lock(&self.shared.state);
        // SAFETY: the caller's contract.
        unsafe { state.evict(&self.shared.ctx.inner.device, BufferId::Caller(buffer)) };
    }

    /// The set of `layout` written with `buffers` (texel bindings through views of their
    /// ranges), made and written on first use — where `preparing` or the cache is not
    /// sealed; else [`GpuError::CacheMiss`] naming `kernel`.
    pub(crate) fn set_for(
        &self,
        kernel: &'static str,
        layout: vk::DescriptorSetLayout,
        buffers: &[&dyn BufferArg],
        preparing: bool,
        write: impl FnOnce(vk::DescriptorSet, &mut Views) -> Result<()>,
    ) -> Result<vk::DescriptorSet> {
        let key: SetKey = (layout, buffers.iter().map(|&b| range_key(b)).collect());
        let ctx = &self.shared.ctx;
        let mut state = super::error::lock(&self.shared.state);
        if let Some(&(_, set)) = state.sets.get(&key) {
            return Ok(set);
        }
        if state.sealed && !preparing {
            return Err(GpuError::CacheMiss { kernel });
        }
        let (pool, set) = state.pools.allocate(ctx, layout)?;
        if let Err(e) = write(set, &mut state.views) {
            // SAFETY: the set is fresh: no command buffer binds it.
            unsafe { state.pools.free(&ctx.inner.device, pool, set) };
            return Err(e);
        }
        state.sets.insert(key, (pool, set));
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

impl CacheShared {
    /// Frees what the cache holds for `id`, a vkrt buffer being dropped.
    ///
    /// # Safety
    /// No pending work uses the buffer `id`.
    pub(crate) unsafe fn evict(&self, id: BufferId) {
        let mut state = super::error::lock(&self.state);
        // SAFETY: a set or view of the buffer's ranges is used only by work that uses it.
        unsafe { state.evict(&self.ctx.inner.device, id) };
    }
}

impl std::fmt::Debug for BindingCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let state = super::error::lock(&self.shared.state);
        f.debug_struct("BindingCache")
            .field("sets", &state.sets.len())
            .field("sealed", &state.sealed)
            .field("evicted", &state.evicted)
            .finish()
    }
}

/// The caches of a context, told when a vkrt buffer drops.
#[derive(Default)]
pub(crate) struct CacheRegistry {
    caches: Mutex<Vec<Weak<CacheShared>>>,
}

impl CacheRegistry {
    pub(crate) fn register(&self, cache: Weak<CacheShared>) {
        let mut caches = super::error::lock(&self.caches);
        caches.retain(|c| c.strong_count() > 0);
        caches.push(cache);
    }

    /// Tells every live cache that the vkrt buffer `id` is dropping.
    ///
    /// # Safety
    /// No pending work uses the buffer.
    pub(crate) unsafe fn evict(&self, id: BufferId) {
        let live: Vec<Arc<CacheShared>> = super::error::lock(&self.caches)
            .iter()
            .filter_map(Weak::upgrade)
            .collect();
        for cache in live {
            // SAFETY: the caller's contract.
            unsafe { cache.evict(id) };
        }
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
