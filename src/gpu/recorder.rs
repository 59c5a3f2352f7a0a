//! The command recorder: dispatches, copies, fills, explicit barriers and profiler scopes,
//! into a command buffer of its own or one the embedding renderer owns.
//!
//! Nothing here inserts a barrier on its own. Each barrier helper is named by the two kinds
//! of work it orders, so a sequence of passes reads like the dependency graph it is; the
//! tests run under synchronization validation, which reports any that are missing.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use ash::vk;
use bytemuck::Pod;

use super::bindings::{check_serves, BindingCache, SetPools, Views};
use super::buffer::{Buffer, BufferArg, Memory};
use super::capture::{interleave, Cmd, SetZero};
use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::hook::{CompletedScope, QuerySlot, RecordedScope, ScopeHook};
use super::kernel::{Kernel, PUSH_CONSTANT_BYTES};
use super::profiler::{
    create_query_pool, PassBytes, Profile, ProfiledDevice, ScopeKind, ScopeRecorder, Submission,
    DEFAULT_QUERY_CAPACITY,
};
use super::stats::{create_counts_pool, DispatchCounts, COUNTS_PER_POOL};
use super::timeline::{self, Calibration, HostSpan};

/// How long `submit_and_wait` waits before calling the device hung.
const SUBMIT_TIMEOUT_NS: u64 = 30 * 60 * 1_000_000_000;

/// Records GPU work. Create with [`Recorder::new`] (own command buffer, submitted by
/// [`Recorder::submit_and_wait`]) or [`Recorder::from_raw`] (the caller's command buffer).
pub struct Recorder {
    ctx: crate::gpu::teardown::Held,
    cmd: vk::CommandBuffer,
    command_pool: Option<vk::CommandPool>,
    /// The recording's own descriptor pools, where it binds from no cache.
    descriptor_pools: SetPools,
    /// The cache it binds from instead ([`Recorder::from_raw_with`]), held until the work
    /// has completed.
    cache: Option<BindingCache>,
    /// Whether this is [`BindingCache::prepare`]'s recording (vkrt's own command buffer,
    /// never submitted), which adds to a sealed cache.
    preparing: bool,
    scopes: ScopeRecorder,
    /// Staging buffers of recorded uploads, alive until the work has executed.
    staging: Vec<Box<dyn std::any::Any + Send>>,
    /// Set once the recorded work is known complete: what read-backs wait for.
    done: Arc<AtomicBool>,
    /// The first thing that went wrong while recording — a Vulkan call that failed
    /// (descriptor pools: out of memory) or a command given arguments it cannot take: what
    /// follows is left out, and the recording reports it ([`Recorder::check`],
    /// `submit_and_wait`, [`RecordedWork::complete`]) instead of running incomplete work.
    failed: Option<GpuError>,
    /// Views of the ranges bound as texel buffers, made once per range (the renderer binds
    /// the same structure in every wave), alive until the work has executed; where the
    /// recording binds from a cache, the cache's.
    views: Views,
    /// What has been recorded so far, counted.
    counts: RecordCounts,
    /// Commands held back instead of recorded ([`Recorder::begin_capture`]).
    capture: Option<Vec<Cmd>>,
    /// Whether every dispatch is a timed scope of its own ([`Recorder::set_dispatch_timestamps`]).
    dispatch_timestamps: bool,
    /// Whether dispatches are recorded empty ([`Recorder::warm_up`]).
    warming: bool,
    /// Host time the recording began, and (a caller's command buffer) was finished.
    started_ns: u64,
    finished_ns: u64,
    /// The hook told every scope ([`Recorder::set_scope_hook`]).
    hook: Option<std::sync::Arc<dyn ScopeHook>>,
    /// Compute-shader invocations counted per dispatch ([`Context::set_pipeline_statistics`]).
    counts_queries: Option<DispatchCounts>,
}

/// Commands a recorder has recorded ([`Recorder::counts`]): what a batched call saves, for
/// tests and tools.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordCounts {
    /// `vkCmdPipelineBarrier`s.
    pub barriers: u64,
    /// Dispatches, direct and indirect.
    pub dispatches: u64,
}

/// A copy of a device buffer into host memory, recorded by [`Recorder::read_back`]; read it
/// once the recorder's work has executed.
pub struct Readback<T: Pod> {
    staging: Arc<Buffer<T>>,
    /// Set when the recording's work is known complete.
    done: Arc<AtomicBool>,
}

impl<T: Pod> Readback<T> {
    /// A read-back of `staging` (host-visible), into which `rec` recorded a copy: `rec`
    /// keeps the buffer alive until its work has completed, whenever this is dropped.
    pub fn from_staging(rec: &mut Recorder, staging: Buffer<T>) -> Self {
        let staging = Arc::new(staging);
        rec.staging.push(Box::new(staging.clone()));
        Self {
            staging,
            done: rec.done.clone(),
        }
    }

    /// The copied elements, once the recording's work is known complete
    /// ([`Recorder::submit_and_wait`] returned, or [`RecordedWork::complete`] was called
    /// after the caller's fence): before, an error, never memory the GPU may still write.
    pub fn read(&self) -> Result<Vec<T>> {
        if !self.done.load(Ordering::Acquire) {
            return Err(GpuError::Usage {
                call: "Readback::read",
                reason: "the work that writes it has not completed: read after \
                         submit_and_wait, or after RecordedWork::complete"
                    .into(),
            });
        }
        self.staging.download()
    }
}

/// Work recorded into a caller-owned command buffer, holding what that command buffer
/// uses (descriptor sets, timestamp queries) until the caller says it has completed.
///
/// Dropped without [`RecordedWork::complete`], it cannot know when the caller's command
/// buffer finishes: on vkrt's own device it waits for the device to go idle; on an adopted
/// device (whose other queues are the caller's) it waits for nothing and hands what the
/// command buffer uses to the context, with a warning in the log, until the renderer calls
/// [`Context::retire`] after its fence ([`Context::holders`] counts them).
#[must_use = "call complete() once the command buffer has executed; dropping it stalls, or keeps its resources until Context::retire"]
pub struct RecordedWork {
    /// Taken only in `drop`.
    recorder: std::mem::ManuallyDrop<Recorder>,
    completed: bool,
}

impl Recorder {
    /// A recorder with its own primary command buffer, in the recording state.
    pub fn new(ctx: &Context) -> Result<Self> {
        Self::new_with(ctx, None)
    }

    /// [`Recorder::new`], binding from `cache` (which [`BindingCache::prepare`] fills
    /// through a recording that is never submitted) and writing no timestamps.
    pub(crate) fn new_with(ctx: &Context, cache: Option<BindingCache>) -> Result<Self> {
        let queries = match cache {
            Some(_) => 0,
            None => DEFAULT_QUERY_CAPACITY,
        };
        let device = &ctx.inner.device;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.inner.queue_family)
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: valid device; the pool is destroyed in Drop (or here on error).
        let pool = unsafe { device.create_command_pool(&pool_info, None) }
            .map_err(vk_err("vkCreateCommandPool"))?;
        // The pool and its command buffer.
        ctx.inner.created(2);
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the pool is ours and unused; the buffer is begun once.
        let cmd = unsafe {
            device
                .allocate_command_buffers(&alloc)
                .and_then(|c| device.begin_command_buffer(c[0], &begin).map(|()| c[0]))
        };
        let cmd = match cmd {
            Ok(c) => c,
            Err(e) => {
                // SAFETY: nothing recorded uses the pool.
                unsafe { device.destroy_command_pool(pool, None) };
                return Err(vk_err("vkAllocateCommandBuffers")(e));
            }
        };
        match Self::wrap(ctx, cmd, Some(pool), queries, cache) {
            Ok(r) => Ok(r),
            Err(e) => {
                // SAFETY: the command buffer was never submitted.
                unsafe { device.destroy_command_pool(pool, None) };
                Err(e)
            }
        }
    }

    /// Records into a command buffer the embedding renderer owns and submits itself.
    ///
    /// # Safety
    /// - `cmd` is a primary command buffer of the context's queue family, in the recording
    ///   state, outside a render pass, and not recorded to concurrently;
    /// - every buffer bound while recording outlives the execution of `cmd`;
    /// - [`RecordedWork::complete`] is called only after `cmd` has finished executing (or
    ///   was never submitted), and before `cmd` is reset or freed.
    pub unsafe fn from_raw(
        ctx: &Context,
        cmd: vk::CommandBuffer,
        query_capacity: u32,
    ) -> Result<Self> {
        Self::wrap(ctx, cmd, None, query_capacity, None)
    }

    /// Records into a command buffer the embedding renderer owns, as
    /// [`Recorder::from_raw`] does, creating no Vulkan object of its own: no timestamp
    /// query pool (scopes become debug labels only; profile with `from_raw` and a query
    /// capacity) and no descriptor pool — every descriptor set and texel view comes from
    /// `cache`, which [`BindingCache::prepare`] filled before the first frame. Kernels are
    /// the context's, compiled by that preparation too.
    ///
    /// # Safety
    /// As [`Recorder::from_raw`].
    pub unsafe fn from_raw_with(
        ctx: &Context,
        cmd: vk::CommandBuffer,
        cache: &BindingCache,
    ) -> Result<Self> {
        check_serves(cache, ctx)?;
        Self::wrap(ctx, cmd, None, 0, Some(cache.clone()))
    }

    fn wrap(
        ctx: &Context,
        cmd: vk::CommandBuffer,
        command_pool: Option<vk::CommandPool>,
        queries: u32,
        cache: Option<BindingCache>,
    ) -> Result<Self> {
        let query_pool = create_query_pool(&ctx.inner.device, queries, ctx.info().timestamps)?;
        ctx.inner.created(query_pool.is_some() as u64);
        let dispatch_timestamps = ctx
            .inner
            .dispatch_timestamps
            .load(std::sync::atomic::Ordering::Relaxed);
        let mut scopes = ScopeRecorder::new(query_pool, queries);
        // Only vkrt's own command buffer, and only when every dispatch is timed, adds query
        // pools while recording: a caller's recording creates no Vulkan object of its own
        // beyond the pool it sized.
        scopes.set_growable(dispatch_timestamps && command_pool.is_some());
        // Counters are made here, before anything is recorded: a caller's recording gets
        // half its query capacity; one binding from a cache, none.
        let counting = ctx
            .inner
            .pipeline_statistics
            .load(std::sync::atomic::Ordering::Relaxed)
            && queries > 0;
        let counts_queries = match counting {
            true => {
                let capacity = match command_pool {
                    Some(_) => COUNTS_PER_POOL,
                    None => (queries / 2).max(1),
                };
                let pool = match create_counts_pool(&ctx.inner.device, capacity) {
                    Ok(p) => p,
                    Err(e) => {
                        if let Some(p) = query_pool {
                            // SAFETY: just created, used by nothing.
                            unsafe { ctx.inner.device.destroy_query_pool(p, None) };
                        }
                        return Err(e);
                    }
                };
                ctx.inner.created(1);
                Some(DispatchCounts::new(pool, capacity, command_pool.is_some()))
            }
            false => None,
        };
        let hook = super::error::lock(&ctx.inner.scope_hook).clone();
        Ok(Self {
            ctx: crate::gpu::teardown::Held::new(ctx, crate::gpu::teardown::Holder::Recorder),
            cmd,
            command_pool,
            descriptor_pools: SetPools::default(),
            preparing: cache.is_some() && command_pool.is_some(),
            cache,
            scopes,
            staging: Vec::new(),
            done: Arc::default(),
            failed: None,
            views: Default::default(),
            counts: RecordCounts::default(),
            capture: None,
            dispatch_timestamps,
            warming: false,
            started_ns: timeline::host_now_ns(),
            finished_ns: 0,
            hook,
            counts_queries,
        })
    }

    /// Times every dispatch recorded from now on as a scope named after its kernel (and
    /// variant), nested in the open pass scopes; the context's
    /// [`Context::set_dispatch_timestamps`] sets the default. Off, a dispatch writes no
    /// timestamp. On, vkrt's own recorder ([`Recorder::new`]) adds a query pool whenever
    /// its pools are full; a caller's ([`Recorder::from_raw`]) keeps the one it sized and
    /// counts the scopes past it in [`Profile::untimed_scopes`]. Dispatches held back to be
    /// interleaved with others (the builds of a batch, which share barriers) are not timed
    /// one by one.
    pub fn set_dispatch_timestamps(&mut self, on: bool) {
        self.dispatch_timestamps = on;
        self.scopes.set_growable(on && self.command_pool.is_some());
    }

    /// Tells `hook` every scope and dispatch recorded from now on, and their ticks once the
    /// work has completed ([`ScopeHook`]); the context's [`Context::set_scope_hook`] sets the
    /// default; `None` tells nothing.
    pub fn set_scope_hook(&mut self, hook: Option<std::sync::Arc<dyn ScopeHook>>) {
        self.hook = hook;
    }

    /// Tells the hook, if any, about a scope opened or (`end`) closed.
    fn tell_hook(
        &self,
        name: &str,
        kind: ScopeKind,
        depth: usize,
        queries: [Option<u32>; 2],
        end: bool,
    ) {
        let Some(hook) = &self.hook else { return };
        let slot = |q: u32| {
            let (pool, index) = self.scopes.locate(q);
            QuerySlot { pool, index }
        };
        let scope = RecordedScope {
            name,
            kind,
            depth: depth as u32,
            command_buffer: self.cmd,
            begin: queries[0].map(slot),
            end: queries[1].map(slot),
        };
        match end {
            false => hook.scope_begun(&scope),
            true => hook.scope_ended(&scope),
        }
    }

    /// Records `f` with every dispatch emptied (zero workgroups) and every fill, copy and
    /// update left out, inside a scope named `warm-up`: each pipeline `f` binds is
    /// dispatched once without touching memory. A driver that compiles a pipeline's code
    /// at its first dispatch (lavapipe's JIT) compiles it here, so the passes timed after
    /// it measure the kernels alone.
    pub fn warm_up<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        self.begin_scope("warm-up");
        let was = std::mem::replace(&mut self.warming, true);
        let r = f(self);
        self.warming = was;
        self.end_scope();
        r
    }

    /// Adds a query pool when the recorder may grow and its pools are full; a failure to
    /// make one leaves the following scopes untimed (counted and reported, not fatal).
    fn reserve_query(&mut self) {
        if !self.scopes.wants_pool() {
            return;
        }
        let capacity = self.scopes.pool_capacity();
        match create_query_pool(&self.ctx.inner.device, capacity, true) {
            Ok(Some(pool)) => {
                self.ctx.inner.created(1);
                self.scopes.add_pool(pool);
            }
            Ok(None) => {}
            Err(e) => {
                log::warn!("no further timestamp query pool: {e}");
                self.scopes.set_growable(false);
            }
        }
    }

    /// Resets query `q` and writes the timestamp into it. Each query is reset as it is
    /// used, not the whole pool up front: the validation layer (1.3.239) keeps state for
    /// every query a command buffer resets and does not release it with the pool — a
    /// whole-pool reset of 32,768 queries grew the process by 4.6 MB per recorder.
    fn write_timestamp(&self, q: u32) {
        let (pool, q) = self.scopes.locate(q);
        let device = &self.ctx.inner.device;
        // SAFETY: recording outside a render pass; `q` is below the pool's capacity.
        unsafe {
            device.cmd_reset_query_pool(self.cmd, pool, q, 1);
            device.cmd_write_timestamp(self.cmd, vk::PipelineStageFlags::BOTTOM_OF_PIPE, pool, q);
        }
    }

    /// The barriers and dispatches recorded so far.
    pub fn counts(&self) -> RecordCounts {
        self.counts
    }

    /// The context this recorder records for.
    pub fn context(&self) -> &Context {
        &self.ctx
    }

    /// The raw command buffer, for mixing in the caller's own commands.
    pub fn command_buffer(&self) -> vk::CommandBuffer {
        self.cmd
    }

    /// Workgroup counts covering `items` with `per_group` items per workgroup, folded into
    /// a 2-D grid when they exceed `maxComputeWorkGroupCount[0]` (kernels use
    /// `linear_group_id()` from `glsl/common/grid.glsl` and bounds-check). Counts beyond
    /// the device's grid come back as they are, and [`Recorder::dispatch`] refuses them.
    pub fn groups_1d(&self, items: u64, per_group: u32) -> [u32; 3] {
        let groups = items.div_ceil(u64::from(per_group.max(1)));
        let max = self.ctx.info().max_workgroup_count;
        let x = groups.min(u64::from(max[0]));
        let y = if x == 0 { 1 } else { groups.div_ceil(x) };
        [x as u32, u32::try_from(y).unwrap_or(u32::MAX), 1]
    }

    /// Binds `buffers` (in the order of the kernel's bindings) and `push` and dispatches
    /// `groups` workgroups.
    pub fn dispatch<P: Pod>(
        &mut self,
        kernel: &Kernel,
        groups: [u32; 3],
        buffers: &[&dyn BufferArg],
        push: &P,
    ) {
        let max = self.ctx.info().max_workgroup_count;
        if (0..3).any(|a| groups[a] > max[a]) {
            let reason = format!(
                "`{}`: {groups:?} workgroups exceed maxComputeWorkGroupCount {max:?}",
                kernel.name()
            );
            self.refuse("Recorder::dispatch", reason);
            return;
        }
        if !self.bind(kernel, buffers, bytemuck::bytes_of(push)) {
            return;
        }
        let groups = if self.warming { [0, 1, 1] } else { groups };
        let bytes = bound_bytes(kernel.blob, buffers);
        self.timed_dispatch(kernel, Cmd::Dispatch(groups), Some(bytes));
    }

    /// Like [`Recorder::dispatch`], with the workgroup counts read from `indirect` at byte
    /// `offset` (three u32) when the dispatch executes. Order the write of those counts
    /// with [`Recorder::compute_to_indirect`].
    pub fn dispatch_indirect<P: Pod>(
        &mut self,
        kernel: &Kernel,
        indirect: &dyn BufferArg,
        offset: u64,
        buffers: &[&dyn BufferArg],
        push: &P,
    ) {
        if offset % 4 != 0 || offset + 12 > indirect.range() {
            let reason = format!("`{}`: indirect offset {offset} out of range", kernel.name());
            self.refuse("Recorder::dispatch_indirect", reason);
            return;
        }
        if !self.bind(kernel, buffers, bytemuck::bytes_of(push)) {
            return;
        }
        let dispatch = match self.warming {
            // Empty and direct: the counts may not have been written yet.
            true => Cmd::Dispatch([0, 1, 1]),
            false => Cmd::DispatchIndirect {
                buffer: indirect.raw(),
                offset: indirect.offset() + offset,
            },
        };
        // The grid, and so what the kernel touches, is the device's to know.
        self.timed_dispatch(kernel, dispatch, None);
    }

    /// Records a dispatch, labelled with its kernel or, with dispatch timestamps on (and not
    /// held back by a capture), inside a scope of that name.
    /// `bytes` are the ranges it binds, where the host knows its grid.
    fn timed_dispatch(&mut self, kernel: &Kernel, dispatch: Cmd, bytes: Option<PassBytes>) {
        if self.dispatch_timestamps && self.capture.is_none() {
            self.begin_scope_of(kernel.name(), ScopeKind::Dispatch);
            self.count_bytes(bytes);
            self.emit(dispatch);
            self.end_scope();
        } else {
            self.count_bytes(bytes);
            self.label_dispatch(kernel);
            let depth = self.scopes.open_scopes();
            if self.capture.is_none() {
                self.tell_hook(kernel.name(), ScopeKind::Dispatch, depth, [None; 2], false);
            }
            self.emit(dispatch);
            if self.capture.is_none() {
                self.tell_hook(kernel.name(), ScopeKind::Dispatch, depth, [None; 2], true);
            }
        }
    }

    /// A debug label naming the kernel (and its variant) at each dispatch, where the
    /// instance has `VK_EXT_debug_utils`: captures show which kernel every dispatch runs.
    fn label_dispatch(&mut self, kernel: &Kernel) {
        if self.ctx.inner.debug_utils.is_some() {
            let name = std::ffi::CString::new(kernel.name().replace('\0', " ")).unwrap_or_default();
            self.emit(Cmd::Label(name));
        }
    }

    /// Whether `buffers` meet the ranges `kernel`'s bindings need ([`Recorder::dispatch`]'s
    /// rule: non-empty, aligned offsets, within the device's limits and their buffers); the
    /// reason where not. Records nothing, so a caller can refuse before it records.
    pub fn check_bindings(
        &self,
        kernel: &Kernel,
        buffers: &[&dyn BufferArg],
    ) -> std::result::Result<(), String> {
        check_ranges(&self.ctx, kernel.blob, buffers)
    }

    /// Binds the kernel's pipeline, a descriptor set of `buffers` and `push`; false (and the
    /// recording marked failed) when no descriptor set could be made.
    fn bind(&mut self, kernel: &Kernel, buffers: &[&dyn BufferArg], push: &[u8]) -> bool {
        let blob = kernel.blob;
        if buffers.len() != blob.bindings.len() {
            let reason = format!(
                "`{}` has bindings {:?} but {} buffers were given",
                blob.name,
                blob.bindings,
                buffers.len()
            );
            return self.refuse("Recorder::dispatch", reason);
        }
        if push.len() > PUSH_CONSTANT_BYTES as usize || (!push.is_empty() && !blob.push_constants) {
            let reason = format!(
                "`{}`: {} push-constant bytes do not fit its layout",
                blob.name,
                push.len()
            );
            return self.refuse("Recorder::dispatch", reason);
        }
        if let Err(reason) = check_ranges(&self.ctx, blob, buffers) {
            return self.refuse("Recorder::dispatch", reason);
        }
        if kernel.context != self.ctx.inner.id {
            // Its pipeline (and layout) are another device's objects.
            let reason = format!("`{}` was made on another context", blob.name);
            return self.refuse("Recorder::dispatch", reason);
        }
        if self.failed.is_some() {
            return false;
        }
        let set = match kernel.pushed {
            true => Ok(SetZero::Pushed(ranges_of(blob, buffers))),
            false => self.set_for(kernel, buffers).map(SetZero::Bound),
        };
        let set = match set {
            Ok(set) => set,
            Err(e) => {
                self.failed.get_or_insert(e);
                return false;
            }
        };
        self.emit(Cmd::Bind {
            pipeline: kernel.pipeline,
            layout: kernel.layout,
            set,
            push: push.to_vec(),
        });
        true
    }

    /// The descriptor set of `kernel` over `buffers`: the cache's, or a fresh one of the
    /// recording's pools.
    fn set_for(
        &mut self,
        kernel: &Kernel,
        buffers: &[&dyn BufferArg],
    ) -> Result<vk::DescriptorSet> {
        let (ctx, blob) = (&self.ctx, kernel.blob);
        let write = |set, views: &mut Views| write_set(ctx, blob, set, buffers, views);
        match &self.cache {
            Some(cache) => {
                cache.set_for(blob.name, kernel.set_layout, buffers, self.preparing, write)
            }
            None => self
                .descriptor_pools
                .allocate(ctx, kernel.set_layout)
                .and_then(|(_, set)| write(set, &mut self.views).map(|()| set)),
        }
    }

    /// `Err` when a Vulkan call failed while recording (the work is incomplete and must not
    /// be submitted); vkrt's recording calls return it before handing the work back.
    pub fn check(&self) -> Result<()> {
        match &self.failed {
            Some(e) => Err(e.clone()),
            None => Ok(()),
        }
    }

    /// Marks the recording failed with `reason` (the first failure is the one reported);
    /// false, for the command to leave itself out.
    fn refuse(&mut self, call: &'static str, reason: String) -> bool {
        self.failed.get_or_insert(GpuError::Usage { call, reason });
        false
    }

    /// Fills the whole buffer with the 32-bit pattern `value`.
    pub fn fill<T: Pod>(&mut self, buffer: &Buffer<T>, value: u32) {
        // The buffer has TRANSFER_DST usage and a size that is a multiple of 4 (Buffer
        // rounds up).
        self.emit(Cmd::Fill {
            buffer: buffer.raw(),
            offset: buffer.offset(),
            size: buffer.range(),
            value,
        });
    }

    /// Fills the first `len` elements of `buffer` with the 32-bit `value` repeated (all of
    /// it when `len` is its length). `T` must be a whole number of 32-bit words.
    pub fn fill_first<T: Pod>(&mut self, buffer: &Buffer<T>, len: usize, value: u32) {
        let elem = std::mem::size_of::<T>();
        if len > buffer.len() || elem % 4 != 0 {
            let reason = format!(
                "fill of {len} elements of {elem} bytes in `{}` ({} elements)",
                buffer.name(),
                buffer.len()
            );
            self.refuse("Recorder::fill_first", reason);
            return;
        }
        if len == 0 || self.failed.is_some() {
            return;
        }
        // Offset 0 and a size of whole 32-bit words inside the buffer (checked above).
        self.emit(Cmd::Fill {
            buffer: buffer.raw(),
            offset: buffer.offset(),
            size: (len * elem) as vk::DeviceSize,
            value,
        });
    }

    /// Fills `len` elements of `buffer` from element `at` on with the 32-bit `value` repeated.
    /// `T` must be a whole number of 32-bit words.
    pub fn fill_range<T: Pod>(&mut self, buffer: &Buffer<T>, at: usize, len: usize, value: u32) {
        let elem = std::mem::size_of::<T>();
        if at + len > buffer.len() || elem % 4 != 0 {
            let reason = format!(
                "fill of {len} elements of {elem} bytes from {at} in `{}` ({} elements)",
                buffer.name(),
                buffer.len()
            );
            self.refuse("Recorder::fill_range", reason);
            return;
        }
        if len == 0 || self.failed.is_some() {
            return;
        }
        // A range of whole 32-bit words inside the buffer (checked above).
        self.emit(Cmd::Fill {
            buffer: buffer.raw(),
            offset: buffer.offset() + (at * elem) as vk::DeviceSize,
            size: (len * elem) as vk::DeviceSize,
            value,
        });
    }

    /// Copies the first `len` elements of `src` into `dst`.
    pub fn copy<T: Pod>(&mut self, src: &Buffer<T>, dst: &Buffer<T>, len: usize) {
        if len > src.len() || len > dst.len() {
            let reason = format!(
                "copy of {len} elements from `{}` to `{}`",
                src.name(),
                dst.name()
            );
            self.refuse("Recorder::copy", reason);
            return;
        }
        // Both buffers have transfer usage and the region is in range.
        self.emit_copy(
            src.raw(),
            dst.raw(),
            vk::BufferCopy {
                src_offset: src.offset(),
                dst_offset: dst.offset(),
                size: (len * std::mem::size_of::<T>()) as u64,
            },
        );
    }

    /// Copies the whole of `src` into the start of `dst` (a range of vkrt's buffer or of the
    /// caller's, with `TRANSFER_DST` usage): a transfer read of `src` and a transfer write of
    /// `dst`, with no barrier — order what wrote `src` before it
    /// ([`Recorder::compute_to_transfer`]) and what reads `dst` after it.
    pub fn copy_into<T: Pod>(&mut self, src: &Buffer<T>, dst: &dyn BufferArg) {
        let bytes = (src.len() * std::mem::size_of::<T>()) as u64;
        let fits = dst.range() >= bytes
            && dst
                .buffer_size()
                .is_none_or(|size| dst.offset() + bytes <= size);
        if !fits {
            let reason = format!(
                "copy of {bytes} bytes from `{}` into a range of {} bytes",
                src.name(),
                dst.range()
            );
            self.refuse("Recorder::copy_into", reason);
            return;
        }
        // Both have transfer usage (vkrt's buffers always; the caller's by the range's
        // contract) and the region is in range (checked above).
        self.emit_copy(
            src.raw(),
            dst.raw(),
            vk::BufferCopy {
                src_offset: src.offset(),
                dst_offset: dst.offset(),
                size: bytes,
            },
        );
    }

    /// Copies `len` elements of `src` from element `src_at` on into `dst` from `dst_at` on.
    pub fn copy_range<T: Pod>(
        &mut self,
        src: &Buffer<T>,
        src_at: usize,
        dst: &Buffer<T>,
        dst_at: usize,
        len: usize,
    ) {
        if src_at + len > src.len() || dst_at + len > dst.len() {
            let reason = format!(
                "copy of {len} elements from `{}` at {src_at} to `{}` at {dst_at}",
                src.name(),
                dst.name()
            );
            self.refuse("Recorder::copy_range", reason);
            return;
        }
        let elem = std::mem::size_of::<T>() as u64;
        // Both buffers have transfer usage and the regions are in range (checked above).
        self.emit_copy(
            src.raw(),
            dst.raw(),
            vk::BufferCopy {
                src_offset: src.offset() + src_at as u64 * elem,
                dst_offset: dst.offset() + dst_at as u64 * elem,
                size: len as u64 * elem,
            },
        );
    }

    /// Records a checked copy: nothing for no bytes or a failed recording.
    fn emit_copy(&mut self, src: vk::Buffer, dst: vk::Buffer, region: vk::BufferCopy) {
        if region.size == 0 || self.failed.is_some() {
            return;
        }
        self.emit(Cmd::Copy { src, dst, region });
    }

    /// Records the upload of `data` into the start of `dst` (a transfer write, through a
    /// staging buffer this recorder keeps until its work has executed). Order it before
    /// kernels read `dst` with [`Recorder::transfer_to_compute`].
    pub fn upload<T: Pod>(&mut self, dst: &Buffer<T>, data: &[T]) -> Result<()> {
        self.upload_at(dst, 0, data)
    }

    /// Records the upload of `data` into `dst` from element `at` on, as
    /// [`Recorder::upload`] does into its start.
    pub fn upload_at<T: Pod>(&mut self, dst: &Buffer<T>, at: usize, data: &[T]) -> Result<()> {
        if at.checked_add(data.len()).is_none_or(|end| end > dst.len()) {
            return Err(GpuError::Usage {
                call: "Recorder::upload_at",
                reason: format!(
                    "{} elements at {at} into `{}` of {}",
                    data.len(),
                    dst.name(),
                    dst.len()
                ),
            });
        }
        if data.is_empty() {
            return Ok(());
        }
        let staging = timeline::host_span("vkrt.upload", || {
            let staging =
                Buffer::<T>::with_memory(&self.ctx, "staging.upload", data.len(), Memory::Upload)?;
            staging.write_mapped(bytemuck::cast_slice(data));
            Ok::<_, GpuError>(staging)
        })?;
        self.ctx.inner.upload_bytes.fetch_add(
            std::mem::size_of_val(data) as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
        self.copy_range(&staging, 0, dst, at, data.len());
        self.staging.push(Box::new(staging));
        Ok(())
    }

    /// Records the write of `data` into `dst` from element `at` on, carried in the command
    /// buffer (`vkCmdUpdateBuffer`: at most 65,536 bytes, for constants a recording knows;
    /// no staging buffer). A transfer write: order it with [`Recorder::transfer_to_compute`]
    /// or [`Recorder::to_accel_build`].
    pub fn update<T: Pod>(&mut self, dst: &Buffer<T>, at: usize, data: &[T]) -> Result<()> {
        let elem = std::mem::size_of::<T>();
        let bytes = std::mem::size_of_val(data);
        if at + data.len() > dst.len() || elem % 4 != 0 || bytes > 65_536 {
            return Err(GpuError::Usage {
                call: "Recorder::update",
                reason: format!(
                    "{} elements of {elem} bytes at {at} into `{}` of {} (whole words, at \
                     most 65,536 bytes)",
                    data.len(),
                    dst.name(),
                    dst.len()
                ),
            });
        }
        if data.is_empty() {
            return Ok(());
        }
        self.ctx
            .inner
            .inline_bytes
            .fetch_add(bytes as u64, std::sync::atomic::Ordering::Relaxed);
        // `dst` has TRANSFER_DST usage; the range is inside it, its offset and size
        // multiples of 4 (buffers start word-aligned, elements are whole words: checked
        // above) and at most 65,536 bytes.
        self.emit(Cmd::Update {
            buffer: dst.raw(),
            offset: dst.offset() + (at * elem) as u64,
            data: bytemuck::cast_slice(data).to_vec(),
        });
        Ok(())
    }

    /// Keeps `value` (e.g. a build's scratch buffers) alive until this recorder's work has
    /// executed and the recorder is dropped.
    pub fn keep_alive<T: Send + 'static>(&mut self, value: T) {
        self.staging.push(Box::new(value));
    }

    /// Records a copy of the whole of `src` into host-visible memory, read with
    /// [`Readback::read`] after the work executed. Order the writes of `src` before with
    /// [`Recorder::compute_to_transfer`], and the copy before the host read with
    /// [`Recorder::transfer_to_host`].
    pub fn read_back<T: Pod>(&mut self, src: &Buffer<T>) -> Result<Readback<T>> {
        let staging =
            Buffer::<T>::with_memory(&self.ctx, "staging.readback", src.len(), Memory::Readback)?;
        self.copy(src, &staging, src.len());
        Ok(Readback::from_staging(self, staging))
    }

    fn memory_barrier(
        &mut self,
        src: (vk::PipelineStageFlags, vk::AccessFlags),
        dst: (vk::PipelineStageFlags, vk::AccessFlags),
    ) {
        self.emit(Cmd::Barrier { src, dst });
    }

    /// Adds the bytes of one dispatch or copy to the open scopes (a warm-up's, which touch
    /// nothing, left out).
    fn count_bytes(&mut self, bytes: Option<PassBytes>) {
        if !self.warming {
            self.scopes.add_bytes(bytes);
        }
    }

    /// Records `cmd`, or holds it back while capturing.
    fn emit(&mut self, cmd: Cmd) {
        if self.warming
            && matches!(
                cmd,
                Cmd::Fill { .. } | Cmd::Copy { .. } | Cmd::Update { .. }
            )
        {
            // A warm-up touches no memory.
            return;
        }
        match &cmd {
            Cmd::Fill { size, .. } => self.count_bytes(Some(PassBytes {
                read: 0,
                written: *size,
            })),
            Cmd::Copy { region, .. } => self.count_bytes(Some(PassBytes {
                read: region.size,
                written: region.size,
            })),
            Cmd::Update { data, .. } => self.count_bytes(Some(PassBytes {
                read: 0,
                written: data.len() as u64,
            })),
            _ => {}
        }
        match &mut self.capture {
            Some(held) => held.push(cmd),
            None => self.record(&cmd),
        }
    }

    /// Starts counting the dispatch about to be recorded, where counting is on.
    fn begin_count(&mut self) -> Option<(vk::QueryPool, u32)> {
        let counts = self.counts_queries.as_mut()?;
        if counts.wants_pool() {
            match create_counts_pool(&self.ctx.inner.device, COUNTS_PER_POOL) {
                Ok(p) => {
                    self.ctx.inner.created(1);
                    counts.add_pool(Some(p));
                }
                Err(e) => {
                    log::warn!("no further pipeline-statistics query pool: {e}");
                    counts.add_pool(None);
                }
            }
        }
        let (pool, q) = counts.take(self.scopes.innermost())?;
        // SAFETY: recording outside a render pass; `q` is below the pool's capacity; no
        // other pipeline-statistics query is active (each spans one dispatch).
        unsafe {
            let device = &self.ctx.inner.device;
            device.cmd_reset_query_pool(self.cmd, pool, q, 1);
            device.cmd_begin_query(self.cmd, pool, q, vk::QueryControlFlags::empty());
        }
        Some((pool, q))
    }

    /// Records `cmd` into the command buffer.
    fn record(&mut self, cmd: &Cmd) {
        let counted = match cmd {
            Cmd::Dispatch(_) | Cmd::DispatchIndirect { .. } => self.begin_count(),
            _ => None,
        };
        self.record_now(cmd);
        if let Some((pool, q)) = counted {
            // SAFETY: the query begun by begin_count around this one dispatch.
            unsafe { self.ctx.inner.device.cmd_end_query(self.cmd, pool, q) };
        }
    }

    fn record_now(&mut self, cmd: &Cmd) {
        let device = &self.ctx.inner.device;
        let c = self.cmd;
        match cmd {
            Cmd::Bind {
                pipeline,
                layout,
                set,
                push,
            } => {
                // SAFETY: recording outside a render pass; the set was written for this
                // layout, or the ranges are pushed into a layout made for pushing, whose
                // kernel has storage bindings only (Recorder::bind, Kernel::pushed); `push`
                // fits the layout's range (checked there).
                unsafe {
                    device.cmd_bind_pipeline(c, vk::PipelineBindPoint::COMPUTE, *pipeline);
                    match set {
                        SetZero::Bound(set) => device.cmd_bind_descriptor_sets(
                            c,
                            vk::PipelineBindPoint::COMPUTE,
                            *layout,
                            0,
                            &[*set],
                            &[],
                        ),
                        SetZero::Pushed(ranges) => {
                            let pd = self.ctx.inner.push_descriptor.as_ref().expect(
                                "a pushed kernel's recorder has push descriptors (Recorder::bind)",
                            );
                            let writes: Vec<vk::WriteDescriptorSet> = ranges
                                .iter()
                                .map(|(binding, info)| {
                                    vk::WriteDescriptorSet::default()
                                        .dst_binding(*binding)
                                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                                        .buffer_info(std::slice::from_ref(info))
                                })
                                .collect();
                            pd.cmd_push_descriptor_set(
                                c,
                                vk::PipelineBindPoint::COMPUTE,
                                *layout,
                                0,
                                &writes,
                            );
                        }
                    }
                    if !push.is_empty() {
                        device.cmd_push_constants(
                            c,
                            *layout,
                            vk::ShaderStageFlags::COMPUTE,
                            0,
                            push,
                        );
                    }
                }
            }
            Cmd::Label(name) => {
                if let Some(du) = &self.ctx.inner.debug_utils {
                    let label = vk::DebugUtilsLabelEXT::default().label_name(name);
                    // SAFETY: recording; the instance has VK_EXT_debug_utils.
                    unsafe { du.cmd_insert_debug_utils_label(c, &label) };
                }
            }
            Cmd::Dispatch(groups) => {
                self.counts.dispatches += 1;
                // SAFETY: recording; a Bind of this kernel precedes it (dispatch binds
                // before it dispatches, and a capture keeps each list's order).
                unsafe { device.cmd_dispatch(c, groups[0], groups[1], groups[2]) };
            }
            Cmd::DispatchIndirect { buffer, offset } => {
                self.counts.dispatches += 1;
                // SAFETY: as Dispatch; the indirect range was checked by dispatch_indirect.
                unsafe { device.cmd_dispatch_indirect(c, *buffer, *offset) };
            }
            Cmd::Fill {
                buffer,
                offset,
                size,
                value,
            } => {
                // SAFETY: recording; the fill's range was checked by its maker (fill,
                // fill_first): inside a buffer with TRANSFER_DST usage, whole words.
                unsafe { device.cmd_fill_buffer(c, *buffer, *offset, *size, *value) };
            }
            Cmd::Copy { src, dst, region } => {
                // SAFETY: recording; both buffers have transfer usage and the region was
                // checked in range by copy / copy_range.
                unsafe { device.cmd_copy_buffer(c, *src, *dst, &[*region]) };
            }
            Cmd::Update {
                buffer,
                offset,
                data,
            } => {
                // SAFETY: recording outside a render pass; checked by update: a range of a
                // TRANSFER_DST buffer, offset and size multiples of 4, at most 65,536 bytes.
                unsafe { device.cmd_update_buffer(c, *buffer, *offset, data) };
            }
            Cmd::Barrier { src, dst } => {
                self.counts.barriers += 1;
                let barrier = vk::MemoryBarrier::default()
                    .src_access_mask(src.1)
                    .dst_access_mask(dst.1);
                // SAFETY: recording, outside a render pass.
                unsafe {
                    device.cmd_pipeline_barrier(
                        c,
                        src.0,
                        dst.0,
                        vk::DependencyFlags::empty(),
                        &[barrier],
                        &[],
                        &[],
                    )
                };
            }
        }
    }

    /// Holds back every command recorded from now on (checks, descriptor sets and counters
    /// as ever; scopes and labels left out) until [`Recorder::end_capture`] hands them over.
    pub(crate) fn begin_capture(&mut self) {
        self.capture = Some(Vec::new());
    }

    /// The commands held back since [`Recorder::begin_capture`]; recording resumes.
    pub(crate) fn end_capture(&mut self) -> Vec<Cmd> {
        self.capture.take().unwrap_or_default()
    }

    /// Records captured sequences interleaved: pass `k` of every sequence, then one
    /// barrier (the union of theirs), for every `k`. The sequences must touch disjoint
    /// memory (the builds of a batch, each in its own structure and scratch).
    pub(crate) fn record_interleaved(&mut self, lists: Vec<Vec<Cmd>>) {
        for cmd in interleave(lists) {
            self.emit(cmd);
        }
    }

    /// Kernel writes (and reads) before → kernel reads and writes after.
    pub fn compute_to_compute(&mut self) {
        self.memory_barrier(COMPUTE_RW, COMPUTE_RW);
    }

    /// Copies and fills before → kernels after.
    pub fn transfer_to_compute(&mut self) {
        self.memory_barrier(TRANSFER_W, COMPUTE_RW);
    }

    /// Kernels before → copies and fills after.
    pub fn compute_to_transfer(&mut self) {
        self.memory_barrier(COMPUTE_RW, TRANSFER_RW);
    }

    /// Copies and fills before → copies and fills after.
    pub fn transfer_to_transfer(&mut self) {
        self.memory_barrier(TRANSFER_W, TRANSFER_RW);
    }

    /// Copies and fills before → indirect dispatch arguments and kernels after (a copied
    /// structure's refit schedule holds its dispatch arguments).
    pub fn transfer_to_indirect(&mut self) {
        self.memory_barrier(TRANSFER_W, INDIRECT_COMPUTE_RW);
    }

    /// Kernel writes before → indirect dispatch arguments (and kernels) after.
    pub fn compute_to_indirect(&mut self) {
        self.memory_barrier(COMPUTE_RW, INDIRECT_COMPUTE_RW);
    }

    /// Copies, fills and kernel writes before → acceleration-structure builds after (which
    /// read vertices and instances as shader reads, and scratch as structure accesses).
    pub fn to_accel_build(&mut self) {
        self.memory_barrier(
            (
                vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::SHADER_WRITE,
            ),
            ACCEL_BUILD_RW,
        );
    }

    /// Acceleration-structure builds before → builds after: a BLAS before the TLAS over it,
    /// and scratch memory reused.
    pub fn accel_build_to_accel_build(&mut self) {
        self.memory_barrier(ACCEL_BUILD_W, ACCEL_BUILD_RW);
    }

    /// Acceleration-structure builds before → kernels that query them after.
    pub fn accel_build_to_compute(&mut self) {
        self.memory_barrier(
            ACCEL_BUILD_W,
            (
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR | vk::AccessFlags::SHADER_READ,
            ),
        );
    }

    /// Everything a build recorded (kernels, copies, fills, indirect reads, and the driver's
    /// builds where the device has them) before → kernels after: the one barrier each of
    /// vkrt's build, update and refit calls ends with, so that what it leaves last is
    /// compute-shader work (`accel::sync::RecordSync::build`).
    pub fn end_of_build(&mut self) {
        let ray_query = self.ctx.info().features.ray_query;
        let (mut src, mut dst) = (
            (
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
            ),
            COMPUTE_RW,
        );
        if ray_query {
            src.0 |= ACCEL_BUILD_W.0;
            src.1 |= ACCEL_BUILD_W.1;
            dst.1 |= vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR;
        }
        self.memory_barrier(src, dst);
    }

    /// Kernel writes before → host reads after the submission completes.
    pub fn compute_to_host(&mut self) {
        self.memory_barrier(COMPUTE_RW, HOST_R);
    }

    /// Copies before → host reads after the submission completes.
    pub fn transfer_to_host(&mut self) {
        self.memory_barrier(TRANSFER_W, HOST_R);
    }

    /// Opens a named pass: a timestamp scope and a debug label. Scopes nest.
    pub fn begin_scope(&mut self, name: &str) {
        self.begin_scope_of(name, ScopeKind::Pass);
    }

    fn begin_scope_of(&mut self, name: &str, kind: ScopeKind) {
        if self.capture.is_some() {
            return;
        }
        self.reserve_query();
        let query = self.scopes.begin(name, kind);
        if let Some(du) = &self.ctx.inner.debug_utils {
            let label_name = std::ffi::CString::new(name.replace('\0', " ")).unwrap_or_default();
            let label = vk::DebugUtilsLabelEXT::default().label_name(&label_name);
            // SAFETY: recording; the instance has VK_EXT_debug_utils.
            unsafe { du.cmd_begin_debug_utils_label(self.cmd, &label) };
        }
        if let Some(q) = query {
            self.write_timestamp(q);
        }
        let depth = self.scopes.open_scopes() - 1;
        self.tell_hook(name, kind, depth, [query, None], false);
    }

    /// Closes the innermost open pass. Without one, nothing is recorded and finishing or
    /// submitting the work is an error.
    pub fn end_scope(&mut self) {
        if self.capture.is_some() {
            return;
        }
        if self.scopes.open_scopes() == 0 {
            self.scopes.end();
            return;
        }
        self.reserve_query();
        let closing = self.scopes.innermost();
        let query = self.scopes.end();
        if let Some(q) = query {
            self.write_timestamp(q);
        }
        if let Some((name, kind, depth, begin)) = closing.map(|i| self.scopes.scope(i)) {
            let name = name.to_string();
            self.tell_hook(&name, kind, depth as usize, [begin, query], true);
        }
        if let Some(du) = &self.ctx.inner.debug_utils {
            // SAFETY: recording; a label was begun in begin_scope.
            unsafe { du.cmd_end_debug_utils_label(self.cmd) };
        }
    }

    /// Runs `f` inside a named pass.
    pub fn scope<R>(&mut self, name: &str, f: impl FnOnce(&mut Self) -> R) -> R {
        self.begin_scope(name);
        let r = f(self);
        self.end_scope();
        r
    }

    /// `Err` where a scope was left open or closed without being opened.
    fn check_closed(&self) -> Result<()> {
        let (open, unmatched) = (self.scopes.open_scopes(), self.scopes.unmatched_ends());
        if open == 0 && unmatched == 0 {
            return Ok(());
        }
        Err(GpuError::Usage {
            call: "Recorder::begin_scope/end_scope",
            reason: format!("{open} scope(s) left open, {unmatched} closed without begin_scope"),
        })
    }

    /// Ends, submits and waits for the recorded work; returns the pass timings.
    pub fn submit_and_wait(mut self) -> Result<Profile> {
        if self.command_pool.is_none() {
            return Err(GpuError::Usage {
                call: "Recorder::submit_and_wait",
                reason: "the command buffer is the caller's: end it with finish() and submit it"
                    .into(),
            });
        }
        self.check_closed()?;
        // Incomplete work is never submitted.
        self.check()?;
        let device = &self.ctx.inner.device;
        let recorded_ns = timeline::host_now_ns();
        // SAFETY: recording state, opened by `new`.
        unsafe { device.end_command_buffer(self.cmd) }.map_err(vk_err("vkEndCommandBuffer"))?;
        // SAFETY: valid device.
        let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
            .map_err(vk_err("vkCreateFence"))?;
        self.ctx.inner.created(1);
        let cmds = [self.cmd];
        let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
        self.ctx
            .inner
            .submits
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let submitted_ns = timeline::host_now_ns();
        let mut waited_ns = submitted_ns;
        let result = {
            let queue = super::error::lock(&self.ctx.inner.queue);
            timeline::profiling_scope("vkrt.submit", || {
                // SAFETY: the queue is externally synchronised by the lock; the command
                // buffer is executable; the fence is unsignalled.
                unsafe { device.queue_submit(*queue, &submit, fence) }
                    .map_err(vk_err("vkQueueSubmit"))
            })
        }
        .and_then(|()| {
            waited_ns = timeline::host_now_ns();
            timeline::profiling_scope("vkrt.wait", || {
                // SAFETY: the fence belongs to this device.
                unsafe { device.wait_for_fences(&[fence], true, SUBMIT_TIMEOUT_NS) }
                    .map_err(vk_err("vkWaitForFences"))
            })
        });
        let completed_ns = timeline::host_now_ns();
        let timed_out = matches!(
            result,
            Err(GpuError::Vulkan {
                code: vk::Result::TIMEOUT,
                ..
            })
        );
        if timed_out && !self.ctx.inner.owns_device {
            // The work may still run, and a wait on the renderer's device or queue is not
            // vkrt's to make: leave the fence, the command buffer and what it uses alive.
            self.leak_in_flight();
        } else {
            // SAFETY: the wait succeeded, the submit never happened, or the device is lost
            // (its objects may then be destroyed), so the fence is idle. A timeout on vkrt's
            // own device is a hung device: wait for idle before destroying.
            unsafe {
                if timed_out {
                    let _ = device.device_wait_idle();
                }
                device.destroy_fence(fence, None);
            }
        }
        match result {
            Err(GpuError::DeviceLost { .. }) => Err(GpuError::DeviceLost {
                last_pass: self.scopes.last_name(),
            }),
            Err(GpuError::Vulkan {
                code: vk::Result::TIMEOUT,
                ..
            }) => Err(GpuError::DeviceLost {
                last_pass: format!("{} (timed out)", self.scopes.last_name()),
            }),
            Err(e) => Err(e),
            Ok(()) => {
                self.done.store(true, Ordering::Release);
                let spans = [
                    ("vkrt.record", self.started_ns, recorded_ns),
                    ("vkrt.submit", submitted_ns, waited_ns),
                    ("vkrt.wait", waited_ns, completed_ns),
                ];
                let profile = self.read_profile(submitted_ns, completed_ns)?;
                for (name, start_ns, end_ns) in spans {
                    super::profiler::record_host_span(HostSpan {
                        name,
                        start_ns,
                        end_ns,
                    });
                }
                super::profiler::record_captured(&profile);
                Ok(profile)
            }
        }
    }

    /// Stops recording into a caller-owned command buffer (which the caller ends and
    /// submits). Call [`RecordedWork::complete`] once it has executed.
    /// `Err` on vkrt's own command buffer, where a command was refused (the error
    /// [`check`](Self::check) returns), or where a scope was left open or closed twice: the
    /// recording is then dropped with the descriptor sets it bound, so the caller resets its
    /// command buffer rather than submit it.
    pub fn finish(mut self) -> Result<RecordedWork> {
        self.finished_ns = timeline::host_now_ns();
        if self.command_pool.is_some() {
            return Err(GpuError::Usage {
                call: "Recorder::finish",
                reason: "the command buffer is vkrt's own: submit it with submit_and_wait()".into(),
            });
        }
        self.check_closed()?;
        // A command left out makes the rest wrong: the caller resets its command buffer.
        self.check()?;
        Ok(RecordedWork {
            recorder: std::mem::ManuallyDrop::new(self),
            completed: false,
        })
    }

    /// The profile of the completed work, submitted at host time `submitted_ns` (or,
    /// a caller's command buffer, finished then) and known complete at `completed_ns`.
    fn read_profile(&self, submitted_ns: u64, completed_ns: u64) -> Result<Profile> {
        let info = self.ctx.info();
        let mut submission = Submission {
            queue_family: self.ctx.inner.queue_family,
            submitted_ns,
            completed_ns,
            timestamp_period_ns: info.timestamp_period_ns,
            valid_bits: 0,
            calibration: None,
        };
        let device = Some(ProfiledDevice {
            device: info.device.clone(),
            driver: info.driver.clone(),
            timestamp_period_ns: info.timestamp_period_ns,
            copy_gib_per_s: self.ctx.copy_baseline(),
        });
        let used = self.scopes.queries_used();
        if used == 0 || !self.scopes.timed() {
            let mut profile = self.scopes.untimed();
            if let Some(counts) = &self.counts_queries {
                counts.attribute(&self.ctx.inner.device, &mut profile.passes)?;
            }
            profile.submissions.push(submission);
            profile.device = device;
            return Ok(profile);
        }
        let mut ticks = vec![0u64; used as usize];
        let per_pool = self.scopes.pool_capacity() as usize;
        for (i, chunk) in ticks.chunks_mut(per_pool).enumerate() {
            let (pool, _) = self.scopes.locate((i * per_pool) as u32);
            // SAFETY: the work writing these queries (the first `chunk.len()` of this pool)
            // has completed; `chunk` holds that many u64s.
            unsafe {
                self.ctx.inner.device.get_query_pool_results(
                    pool,
                    0,
                    chunk,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
            }
            .map_err(vk_err("vkGetQueryPoolResults"))?;
        }
        let bits = super::info::timestamp_bits(
            &self.ctx.inner.instance,
            self.ctx.inner.physical_device,
            self.ctx.inner.queue_family,
        );
        let mut profile = self.scopes.resolve(&ticks, info.timestamp_period_ns, bits);
        if let Some(counts) = &self.counts_queries {
            counts.attribute(&self.ctx.inner.device, &mut profile.passes)?;
        }
        submission.valid_bits = bits;
        // Calibrated now that the work is done; else the first tick is put at the submit.
        submission.calibration = self
            .ctx
            .inner
            .calibrator
            .as_ref()
            .and_then(|c| c.sample())
            .or_else(|| {
                let first = profile
                    .passes
                    .iter()
                    .filter_map(|p| p.ticks)
                    .map(|t| t[0])
                    .min()?;
                Some(Calibration {
                    method: timeline::SUBMIT_ALIGNED,
                    gpu_tick: first,
                    host_ns: submitted_ns,
                    max_deviation_ns: None,
                })
            });
        for p in &mut profile.passes {
            p.submission = Some(0);
        }
        if let Some(hook) = &self.hook {
            let slot = |q: u32| {
                let (pool, index) = self.scopes.locate(q);
                QuerySlot { pool, index }
            };
            let completed: Vec<CompletedScope<'_>> = self
                .scopes
                .timed_scopes()
                .map(|(i, name, kind, b, e)| CompletedScope {
                    name,
                    kind,
                    depth: profile.passes[i].depth,
                    queries: [slot(b), slot(e)],
                    ticks: profile.passes[i].ticks.unwrap_or_default(),
                    invocations: profile.passes[i].invocations,
                })
                .collect();
            hook.completed(&completed, &submission);
        }
        profile.submissions.push(submission);
        profile.device = device;
        Ok(profile)
    }
}

impl RecordedWork {
    /// Reads the pass timings and releases what the command buffer used.
    ///
    /// # Safety
    /// The command buffer has finished executing (or was never submitted).
    pub unsafe fn complete(mut self) -> Result<Profile> {
        self.completed = true;
        self.recorder.done.store(true, Ordering::Release);
        self.recorder.check()?;
        let r = &self.recorder;
        r.read_profile(r.finished_ns, timeline::host_now_ns())
            .inspect(super::profiler::record_captured)
    }
}

impl Drop for RecordedWork {
    fn drop(&mut self) {
        // SAFETY: taken once, here, and not used after.
        let recorder = unsafe { std::mem::ManuallyDrop::take(&mut self.recorder) };
        if self.completed {
            return;
        }
        // The caller's command buffer may still be executing. On vkrt's own device, wait
        // before the recorder releases what it uses (a lost device has nothing left to wait
        // for); on an adopted one a device-wide wait is not vkrt's to make: the context keeps
        // the recorder until the renderer retires it after its fence.
        let ctx = recorder.ctx.clone();
        if ctx.inner.owns_device {
            if ctx.wait_idle().is_ok() {
                recorder.done.store(true, Ordering::Release);
            }
        } else {
            log::warn!(
                "vkrt: RecordedWork dropped without complete(): what its command buffer uses is \
                 kept until Context::retire() is called after the renderer's fence"
            );
            ctx.keep_until_retired(recorder);
        }
    }
}

impl Recorder {
    /// Leaves alive everything the recorded commands use, for work that may still be
    /// executing where vkrt may not wait for it: handles dropped from the lists stay alive,
    /// and the staging buffers are forgotten with their memory (each holds a clone of the
    /// context, which therefore stays too).
    fn leak_in_flight(&mut self) {
        self.descriptor_pools.leak();
        self.views.leak();
        self.scopes.pools.clear();
        if let Some(c) = self.counts_queries.as_mut() {
            c.pools.clear();
        }
        std::mem::forget(std::mem::take(&mut self.staging));
        // A shared cache must outlive the sets this command buffer binds.
        std::mem::forget(self.cache.take());
        // An own command buffer still pending keeps its pool.
        self.command_pool = None;
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        let device = &self.ctx.inner.device;
        // SAFETY: an owned command buffer was either waited for in `submit_and_wait` or never
        // submitted; a caller-owned one reaches here through `RecordedWork::complete` (whose
        // contract says it has executed) or was never handed over. Either way nothing pending
        // uses these pools.
        unsafe {
            self.descriptor_pools.destroy(device);
            self.views.destroy(device);
            for pool in self.scopes.pools.drain(..) {
                device.destroy_query_pool(pool, None);
            }
            for pool in self
                .counts_queries
                .iter_mut()
                .flat_map(|c| c.pools.drain(..))
            {
                device.destroy_query_pool(pool, None);
            }
            if let Some(pool) = self.command_pool.take() {
                // Freed before the pool goes: destroying the pool alone frees it too, but the
                // validation layer (1.3.239) then keeps the buffer's synchronization state,
                // about 4.6 MB per recorder (measured: 400 recorders grew the process by
                // 1.9 GB).
                device.free_command_buffers(pool, &[self.cmd]);
                device.destroy_command_pool(pool, None);
            }
        }
    }
}

/// Indirect dispatch arguments and kernels, as readers after a barrier.
const INDIRECT_COMPUTE_RW: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::from_raw(
        vk::PipelineStageFlags::DRAW_INDIRECT.as_raw()
            | vk::PipelineStageFlags::COMPUTE_SHADER.as_raw(),
    ),
    vk::AccessFlags::from_raw(
        vk::AccessFlags::INDIRECT_COMMAND_READ.as_raw()
            | vk::AccessFlags::SHADER_READ.as_raw()
            | vk::AccessFlags::SHADER_WRITE.as_raw(),
    ),
);

const COMPUTE_RW: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::COMPUTE_SHADER,
    vk::AccessFlags::from_raw(
        vk::AccessFlags::SHADER_READ.as_raw() | vk::AccessFlags::SHADER_WRITE.as_raw(),
    ),
);
const TRANSFER_W: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::TRANSFER,
    vk::AccessFlags::TRANSFER_WRITE,
);
const TRANSFER_RW: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::TRANSFER,
    vk::AccessFlags::from_raw(
        vk::AccessFlags::TRANSFER_READ.as_raw() | vk::AccessFlags::TRANSFER_WRITE.as_raw(),
    ),
);
const HOST_R: (vk::PipelineStageFlags, vk::AccessFlags) =
    (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ);
const ACCEL_BUILD_W: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
    vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
);
const ACCEL_BUILD_RW: (vk::PipelineStageFlags, vk::AccessFlags) = (
    vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
    vk::AccessFlags::from_raw(
        vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR.as_raw()
            | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR.as_raw()
            | vk::AccessFlags::SHADER_READ.as_raw(),
    ),
);

/// The ranges of `buffers`, by `blob`'s binding numbers (pushed, or written into a set).
fn ranges_of(
    blob: &super::shader::ShaderBlob,
    buffers: &[&dyn BufferArg],
) -> Vec<(u32, vk::DescriptorBufferInfo)> {
    blob.bindings
        .iter()
        .zip(buffers)
        .map(|(&binding, b)| {
            let info = vk::DescriptorBufferInfo {
                buffer: b.raw(),
                offset: b.offset(),
                range: b.range(),
            };
            (binding, info)
        })
        .collect()
}

/// Writes `buffers` into `set` (a fresh set of `blob`'s layout, used by no command buffer
/// yet): storage ranges, and texel bindings through RGBA32UI views of their ranges.
fn write_set(
    ctx: &Context,
    blob: &super::shader::ShaderBlob,
    set: vk::DescriptorSet,
    buffers: &[&dyn BufferArg],
    views: &mut Views,
) -> Result<()> {
    let ranges = ranges_of(blob, buffers);
    let mut texel = Vec::new();
    for (&binding, b) in blob.bindings.iter().zip(buffers) {
        if blob.texel_bindings.contains(&binding) {
            texel.push([views.of(ctx, *b)?]);
        }
    }
    let mut next_view = texel.iter();
    let writes: Vec<vk::WriteDescriptorSet> = ranges
        .iter()
        .map(|(binding, info)| {
            let w = vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(*binding)
                .descriptor_type(super::kernel::descriptor_type(blob, *binding));
            match blob.texel_bindings.contains(binding) {
                true => w.texel_buffer_view(next_view.next().expect("one view per texel binding")),
                false => w.buffer_info(std::slice::from_ref(info)),
            }
        })
        .collect();
    // SAFETY: the set is fresh (no command buffer binds it yet) and of this blob's layout;
    // the infos and views outlive the call.
    unsafe { ctx.inner.device.update_descriptor_sets(&writes, &[]) };
    Ok(())
}

/// The ranges a kernel's storage bindings get are the bounds its accesses trust: each must
/// be non-empty, start at an offset the device allows, lie within the device's
/// `maxStorageBufferRange` (lavapipe: 128 MiB; a longer range is invalid, and without the
/// validation layer a kernel past the limit reads and writes memory it does not own) and,
/// for vkrt's own buffers, within the buffer. Texel bindings are checked when their view is
/// made.
/// The bytes a dispatch of `blob` over `buffers` reads and writes: each bound range read
/// unless the kernel only writes it, written unless it only reads it.
fn bound_bytes(blob: &super::shader::ShaderBlob, buffers: &[&dyn BufferArg]) -> PassBytes {
    let mut bytes = PassBytes::default();
    for (&binding, buffer) in blob.bindings.iter().zip(buffers) {
        let range = buffer.range();
        if !blob.write_only_bindings.contains(&binding) {
            bytes.read += range;
        }
        if !blob.read_only_bindings.contains(&binding) {
            bytes.written += range;
        }
    }
    bytes
}

fn check_ranges(
    ctx: &Context,
    blob: &super::shader::ShaderBlob,
    buffers: &[&dyn BufferArg],
) -> std::result::Result<(), String> {
    let info = ctx.info();
    let align = info.min_storage_buffer_offset_alignment.max(1);
    for (&binding, b) in blob.bindings.iter().zip(buffers) {
        if blob.texel_bindings.contains(&binding) {
            continue;
        }
        let (offset, range) = (b.offset(), b.range());
        let fits_buffer = b
            .buffer_size()
            .is_none_or(|size| offset.checked_add(range).is_some_and(|end| end <= size));
        if range == 0
            || offset % align != 0
            || range > info.max_storage_buffer_range
            || !fits_buffer
        {
            return Err(format!(
                "`{}` binding {binding}: a range of {range} bytes at offset {offset}{} (ranges \
                 non-empty, offsets a multiple of {align}, at most {} bytes: the device's \
                 maxStorageBufferRange)",
                blob.name,
                b.buffer_size()
                    .map_or(String::new(), |s| format!(" of a {s}-byte buffer")),
                info.max_storage_buffer_range
            ));
        }
    }
    Ok(())
}
