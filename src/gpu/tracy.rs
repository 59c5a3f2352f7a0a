//! vkrt's passes and dispatches as GPU zones of the application's own Tracy (feature
//! `tracy`): a [`ScopeHook`] over `tracy-client`'s GPU context. Each timed scope becomes a
//! zone when it is recorded (`GpuContext::span_alloc`, `GpuSpan::end_zone`), and gets its
//! ticks when the work has completed (`upload_timestamp_start` / `_end`, in the order the
//! scopes nest, as Tracy asks). Tracy records only where the application's `tracy-client`
//! has its `enable` feature (its default); otherwise every call is empty.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use tracy_client::{Client, GpuContext, GpuContextType, GpuSpan};

use super::context::Context;
use super::error::{lock, GpuError, Result};
use super::hook::{CompletedScope, QuerySlot, RecordedScope, ScopeHook};
use super::profiler::Submission;

/// The Tracy GPU context vkrt's recorders report to; register it on a context with
/// [`Context::set_scope_hook`] (or on one recorder with
/// [`super::Recorder::set_scope_hook`]).
pub struct TracyScopes {
    gpu: GpuContext,
    /// Zones recorded and not yet given their ticks, by their begin query.
    zones: Mutex<HashMap<QuerySlot, GpuSpan>>,
    /// Scopes Tracy had no room for (it holds at most 32,767 zones awaiting ticks).
    dropped: AtomicUsize,
}

impl TracyScopes {
    /// A GPU context of `client` named `name` for `ctx`'s queue, its clock started at a
    /// tick read now ([`Context::calibrate`]). `Err` where the device has no timestamps.
    pub fn new(ctx: &Context, client: Client, name: &str) -> Result<Arc<Self>> {
        let missing = || GpuError::MissingCapability {
            device: ctx.info().device.clone(),
            what: "timestamp queries (for Tracy's GPU zones)".into(),
        };
        let start = ctx.calibrate()?.ok_or_else(missing)?;
        let gpu = client
            .new_gpu_context(
                Some(name),
                GpuContextType::Vulkan,
                start.gpu_tick as i64,
                ctx.info().timestamp_period_ns,
            )
            .map_err(|e| GpuError::Usage {
                call: "TracyScopes::new",
                reason: e.to_string(),
            })?;
        Ok(Arc::new(Self {
            gpu,
            zones: Mutex::new(HashMap::new()),
            dropped: AtomicUsize::new(0),
        }))
    }

    /// Scopes left out because Tracy had too many zones awaiting ticks.
    pub fn dropped_scopes(&self) -> usize {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl ScopeHook for TracyScopes {
    fn scope_begun(&self, scope: &RecordedScope<'_>) {
        let Some(begin) = scope.begin else { return };
        match self.gpu.span_alloc(scope.name, "vkrt", file!(), line!()) {
            Ok(span) => {
                lock(&self.zones).insert(begin, span);
            }
            Err(_) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn scope_ended(&self, scope: &RecordedScope<'_>) {
        let Some(begin) = scope.begin else { return };
        let mut zones = lock(&self.zones);
        match scope.end {
            Some(_) => {
                if let Some(span) = zones.get_mut(&begin) {
                    span.end_zone();
                }
            }
            // Begun with a time, ended without (queries ran out): no zone.
            None => drop(zones.remove(&begin)),
        }
    }

    fn completed(&self, scopes: &[CompletedScope<'_>], _: &Submission) {
        let mut zones = lock(&self.zones);
        // Starts and ends in the order they were recorded: a scope's end comes before the
        // start of the next scope at its depth or above.
        let mut open: Vec<(u32, GpuSpan, u64)> = Vec::new();
        for s in scopes {
            while open.last().is_some_and(|o| o.0 >= s.depth) {
                let (_, span, end) = open.pop().expect("checked");
                span.upload_timestamp_end(end as i64);
            }
            if let Some(span) = zones.remove(&s.queries[0]) {
                span.upload_timestamp_start(s.ticks[0] as i64);
                open.push((s.depth, span, s.ticks[1]));
            }
        }
        while let Some((_, span, end)) = open.pop() {
            span.upload_timestamp_end(end as i64);
        }
    }
}
