//! A record-time hook on vkrt's scopes, for a renderer's own GPU profiler: each pass and
//! dispatch is announced as it is recorded, with the timestamp queries (pool and index) it
//! wrote, and the raw ticks of those queries are handed over once the work has completed —
//! what Tracy's Vulkan zones and wgpu-profiler-style profilers build their GPU zones from.

use ash::vk;

use super::profiler::{ScopeKind, Submission};

/// A timestamp query vkrt wrote: its pool and its index in the pool.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct QuerySlot {
    /// The query pool (vkrt's own, alive until the recording's work has completed).
    pub pool: vk::QueryPool,
    /// The query's index in `pool`.
    pub index: u32,
}

/// A scope as it is recorded, told to [`ScopeHook::scope_begun`] (without `end`) and
/// [`ScopeHook::scope_ended`].
#[derive(Clone, Copy, Debug)]
pub struct RecordedScope<'a> {
    /// The scope's name: a pass's, or a dispatch's kernel and variant.
    pub name: &'a str,
    /// A pass, or one dispatch.
    pub kind: ScopeKind,
    /// Scopes open around it.
    pub depth: u32,
    /// The command buffer it is recorded into.
    pub command_buffer: vk::CommandBuffer,
    /// The query its begin timestamp was written into; `None` where it is untimed (no
    /// timestamps on the device, queries ran out, or a dispatch while dispatch timestamps
    /// are off).
    pub begin: Option<QuerySlot>,
    /// At its end, the query its end timestamp was written into.
    pub end: Option<QuerySlot>,
}

/// A timed scope whose work has completed, told to [`ScopeHook::completed`].
#[derive(Clone, Copy, Debug)]
pub struct CompletedScope<'a> {
    /// As recorded.
    pub name: &'a str,
    /// As recorded.
    pub kind: ScopeKind,
    /// As recorded.
    pub depth: u32,
    /// The queries of its begin and end timestamps.
    pub queries: [QuerySlot; 2],
    /// Their raw ticks (masked to the queue's `timestampValidBits`; nanoseconds are ticks ×
    /// [`Submission::timestamp_period_ns`]).
    pub ticks: [u64; 2],
    /// Compute-shader invocations inside it, where counted
    /// ([`super::Context::set_pipeline_statistics`]).
    pub invocations: Option<u64>,
}

/// What a renderer registers ([`super::Context::set_scope_hook`],
/// [`super::Recorder::set_scope_hook`]) to forward vkrt's passes to its own profiler.
///
/// `scope_begun` and `scope_ended` are called on the recording thread right after the
/// timestamp (if any) is recorded, in nesting order; `completed` once per recording, when
/// [`super::Recorder::submit_and_wait`] or [`super::RecordedWork::complete`] has read the
/// queries back, before their pools are released.
pub trait ScopeHook: Send + Sync {
    /// A scope was opened.
    fn scope_begun(&self, scope: &RecordedScope<'_>);
    /// A scope was closed (`end` set where it is timed).
    fn scope_ended(&self, scope: &RecordedScope<'_>);
    /// The timed scopes of a completed recording, in opening order, with the submission
    /// that says how their ticks map onto the host's clock.
    fn completed(&self, scopes: &[CompletedScope<'_>], submission: &Submission) {
        let _ = (scopes, submission);
    }
}
