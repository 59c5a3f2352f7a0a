//! GPU pass timing: timestamp queries around nested named scopes, read back after the
//! submission completes and turned into per-pass milliseconds via `timestampPeriod`.
//!
//! The same name is the debug-utils label (RenderDoc, Nsight, validation messages) and the
//! crash marker reported on `DEVICE_LOST`. `Profile::write_chrome_trace` exports the
//! Chrome trace-event JSON that Perfetto (ui.perfetto.dev) and chrome://tracing open: the
//! host's spans and the device's passes on one time axis (`timeline`).

use std::path::Path;

use ash::vk;
use serde::Serialize;

use super::error::{vk_err, GpuError, Result};
use super::timeline::{Calibration, HostSpan};

/// Timestamp queries one recorder reserves by default (two per scope).
pub const DEFAULT_QUERY_CAPACITY: u32 = 32768;

#[derive(Debug)]
struct Scope {
    name: String,
    kind: ScopeKind,
    depth: u32,
    parent: Option<usize>,
    begin: Option<u32>,
    end: Option<u32>,
    /// The bytes its dispatches and copies bound; `None` once one of unknown size ran.
    bytes: Option<PassBytes>,
}

/// The bytes a scope's work reads and writes, as far as the host knows them when it
/// records: each storage or texel range bound to a dispatch whose grid the host set (one
/// read per range the kernel reads, one write per range it writes, by the kernel's
/// `readonly` and `writeonly` declarations), and each copy, fill and update. Exact for a
/// kernel that streams once through buffers sized to its data (the copy baseline, a scan or
/// sort of a fresh build); more than it moved where a bound buffer has room to spare (a
/// wave's queues past its live rays, scratch kept from a larger build); and a walk's nodes
/// count once, however often some are read and however many are never.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PassBytes {
    /// Bytes read.
    pub read: u64,
    /// Bytes written.
    pub written: u64,
}

impl PassBytes {
    /// Read plus written.
    pub fn total(&self) -> u64 {
        self.read + self.written
    }

    /// GiB per second moved in `ms` milliseconds.
    pub fn gib_per_s(&self, ms: f64) -> f64 {
        self.total() as f64 / (ms / 1e3) / f64::from(1u32 << 30)
    }
}

impl std::ops::Add for PassBytes {
    type Output = PassBytes;
    fn add(self, o: PassBytes) -> PassBytes {
        PassBytes {
            read: self.read + o.read,
            written: self.written + o.written,
        }
    }
}

impl std::iter::Sum for PassBytes {
    fn sum<I: Iterator<Item = PassBytes>>(iter: I) -> PassBytes {
        iter.fold(PassBytes::default(), |a, b| a + b)
    }
}

/// The recording side: hands out query indices and remembers the scope tree.
///
/// Queries live in pools of `capacity` each; query `q` is index `q % capacity` of pool
/// `q / capacity`. A recorder that may grow ([`ScopeRecorder::wants_pool`]) adds a pool when
/// the last one is full; one that may not leaves later scopes untimed and counts them.
pub(crate) struct ScopeRecorder {
    pub(crate) pools: Vec<vk::QueryPool>,
    capacity: u32,
    /// Whether the recorder may add pools while recording.
    grow: bool,
    next_query: u32,
    scopes: Vec<Scope>,
    open: Vec<usize>,
    /// `end` calls without an open scope: a usage error reported when the work is finished.
    unmatched_ends: usize,
    /// Scopes left untimed because the query capacity ran out.
    untimed: usize,
}

impl ScopeRecorder {
    pub(crate) fn new(pool: Option<vk::QueryPool>, capacity: u32) -> Self {
        Self {
            pools: pool.into_iter().collect(),
            capacity,
            grow: false,
            next_query: 0,
            scopes: Vec::new(),
            open: Vec::new(),
            unmatched_ends: 0,
            untimed: 0,
        }
    }

    /// Lets the recorder add pools as they fill ([`ScopeRecorder::add_pool`]).
    pub(crate) fn set_growable(&mut self, grow: bool) {
        self.grow = grow;
    }

    /// Whether the next query needs a pool the recorder should add first.
    pub(crate) fn wants_pool(&self) -> bool {
        self.grow && !self.pools.is_empty() && self.next_query >= self.queries_held()
    }

    /// A further pool of `capacity` queries.
    pub(crate) fn add_pool(&mut self, pool: vk::QueryPool) {
        self.pools.push(pool);
    }

    /// The capacity of each pool.
    pub(crate) fn pool_capacity(&self) -> u32 {
        self.capacity
    }

    fn queries_held(&self) -> u32 {
        self.capacity.saturating_mul(self.pools.len() as u32)
    }

    /// The pool and the index in it of query `q`.
    pub(crate) fn locate(&self, q: u32) -> (vk::QueryPool, u32) {
        (self.pools[(q / self.capacity) as usize], q % self.capacity)
    }

    /// Whether scopes are timed at all (the device has timestamps and a pool was made).
    pub(crate) fn timed(&self) -> bool {
        !self.pools.is_empty()
    }

    fn take_query(&mut self) -> Option<u32> {
        (self.timed() && self.next_query < self.queries_held()).then(|| {
            self.next_query += 1;
            self.next_query - 1
        })
    }

    /// Opens a scope; returns the query to write a timestamp into, if any.
    pub(crate) fn begin(&mut self, name: &str, kind: ScopeKind) -> Option<u32> {
        let begin = self.take_query();
        if begin.is_none() && self.timed() {
            self.untimed += 1;
        }
        self.scopes.push(Scope {
            name: name.to_string(),
            kind,
            depth: self.open.len() as u32,
            parent: self.open.last().copied(),
            begin,
            end: None,
            bytes: Some(PassBytes::default()),
        });
        self.open.push(self.scopes.len() - 1);
        begin
    }

    /// Closes the innermost scope; returns the query to write, if any.
    pub(crate) fn end(&mut self) -> Option<u32> {
        let Some(index) = self.open.pop() else {
            // Reported when the work is finished or submitted (`Recorder::check_closed`).
            self.unmatched_ends += 1;
            return None;
        };
        let end = if self.scopes[index].begin.is_some() {
            let end = self.take_query();
            if end.is_none() {
                // Begun but never ended: a scope without a time, counted as one.
                self.untimed += 1;
            }
            end
        } else {
            None
        };
        self.scopes[index].end = end;
        end
    }

    /// Adds the bytes of one dispatch or copy to every open scope; `None` (a grid the host
    /// does not know) leaves them without a byte count.
    pub(crate) fn add_bytes(&mut self, t: Option<PassBytes>) {
        for &i in &self.open {
            let s = &mut self.scopes[i];
            s.bytes = match (s.bytes, t) {
                (Some(a), Some(b)) => Some(a + b),
                _ => None,
            };
        }
    }

    pub(crate) fn open_scopes(&self) -> usize {
        self.open.len()
    }

    pub(crate) fn unmatched_ends(&self) -> usize {
        self.unmatched_ends
    }

    pub(crate) fn last_name(&self) -> String {
        self.scopes
            .last()
            .map_or_else(|| "none".to_string(), |s| s.name.clone())
    }

    pub(crate) fn queries_used(&self) -> u32 {
        self.next_query
    }

    /// Turns raw timestamps (indexed by query) into a profile.
    pub(crate) fn resolve(&self, ticks: &[u64], period_ns: f32, valid_bits: u32) -> Profile {
        let mask = if valid_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << valid_bits) - 1
        };
        let origin = self
            .scopes
            .iter()
            .filter_map(|s| s.begin.map(|q| ticks[q as usize] & mask))
            .min()
            .unwrap_or(0);
        let to_ms = |t: u64| (t.wrapping_sub(origin) & mask) as f64 * f64::from(period_ns) / 1e6;
        let passes = self
            .scopes
            .iter()
            .map(|s| {
                let ticks = match (s.begin, s.end) {
                    (Some(b), Some(e)) => {
                        Some([ticks[b as usize] & mask, ticks[e as usize] & mask])
                    }
                    _ => None,
                };
                let timed = ticks.map(|[b, e]| {
                    (
                        to_ms(b),
                        (e.wrapping_sub(b) & mask) as f64 * f64::from(period_ns) / 1e6,
                    )
                });
                PassTime {
                    name: s.name.clone(),
                    kind: s.kind,
                    depth: s.depth,
                    parent: s.parent,
                    start_ms: timed.map(|t| t.0),
                    ms: timed.map(|t| t.1),
                    ticks,
                    submission: None,
                    invocations: None,
                    bytes: s.bytes,
                }
            })
            .collect();
        if self.untimed > 0 {
            log::warn!(
                "{} of {} scopes untimed: the recorder's {} timestamp queries ran out \
                 (Recorder::from_raw takes the count)",
                self.untimed,
                self.scopes.len(),
                self.queries_held()
            );
        }
        Profile {
            passes,
            untimed_scopes: self.untimed,
            ..Profile::default()
        }
    }

    /// The queries of every timed scope, in opening order, with its name and kind (what a
    /// [`super::ScopeHook`] is told at completion).
    pub(crate) fn timed_scopes(&self) -> impl Iterator<Item = (usize, &str, ScopeKind, u32, u32)> {
        self.scopes
            .iter()
            .enumerate()
            .filter_map(|(i, s)| Some((i, s.name.as_str(), s.kind, s.begin?, s.end?)))
    }

    /// The innermost open scope.
    pub(crate) fn innermost(&self) -> Option<usize> {
        self.open.last().copied()
    }

    /// Scope `i`'s name, kind, depth and begin query.
    pub(crate) fn scope(&self, i: usize) -> (&str, ScopeKind, u32, Option<u32>) {
        let s = &self.scopes[i];
        (s.name.as_str(), s.kind, s.depth, s.begin)
    }

    /// The scope tree without times (no timestamp support).
    pub(crate) fn untimed(&self) -> Profile {
        debug_assert_eq!(self.next_query, 0);
        self.resolve(&[], 1.0, 64)
    }
}

/// Whether a scope is a pass ([`super::Recorder::begin_scope`]) or one dispatch timed on
/// its own ([`super::Recorder::set_dispatch_timestamps`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScopeKind {
    /// A named pass.
    #[default]
    Pass,
    /// One dispatch, named after its kernel and variant.
    Dispatch,
}

/// One scope's timing. `None` times mean the device has no timestamps or the query
/// capacity ran out.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PassTime {
    /// The scope's name (also its debug-utils label).
    pub name: String,
    /// A pass or one dispatch.
    pub kind: ScopeKind,
    /// Nesting depth: 0 for an outermost scope.
    pub depth: u32,
    /// Index of the enclosing scope in `Profile::passes`.
    pub parent: Option<usize>,
    /// Start, in milliseconds after the earliest timed scope of the submission began.
    pub start_ms: Option<f64>,
    /// Duration in milliseconds.
    pub ms: Option<f64>,
    /// The raw device ticks of its begin and end timestamps (masked to the queue's
    /// `timestampValidBits`), for a profiler of the caller's own.
    pub ticks: Option<[u64; 2]>,
    /// Index of its submission in [`Profile::submissions`]: how its ticks map onto host time.
    pub submission: Option<usize>,
    /// Compute-shader invocations of the dispatches inside it (pipeline-statistics queries,
    /// [`super::Context::set_pipeline_statistics`]); `None` when not counted.
    pub invocations: Option<u64>,
    /// The bytes its work read and wrote, where the host knows them ([`PassBytes`]); `None`
    /// where an indirect dispatch inside took its grid from the device.
    pub bytes: Option<PassBytes>,
}

/// One submission's place on the host's clock.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Submission {
    /// The queue family it ran on (each is a track of the trace).
    pub queue_family: u32,
    /// Host time ([`super::timeline::host_ns`]) just before `vkQueueSubmit`; for a caller's
    /// command buffer, when its recording was finished.
    pub submitted_ns: u64,
    /// Host time when its wait returned; for a caller's command buffer, when it was completed.
    pub completed_ns: u64,
    /// Nanoseconds per tick (`timestampPeriod`).
    pub timestamp_period_ns: f32,
    /// The queue's `timestampValidBits`.
    pub valid_bits: u32,
    /// How its ticks map onto host time; `None` where it has no timed scope.
    pub calibration: Option<Calibration>,
}

impl Submission {
    /// The host time (nanoseconds, [`super::timeline::host_ns`]'s clock) of device `tick`.
    pub fn host_ns_of(&self, tick: u64) -> Option<f64> {
        let c = self.calibration?;
        let mask = match self.valid_bits {
            0 | 64.. => u64::MAX,
            bits => (1u64 << bits) - 1,
        };
        // The shorter way round the valid bits: a tick may precede the calibration's.
        let ahead = tick.wrapping_sub(c.gpu_tick) & mask;
        let delta = match ahead > mask / 2 {
            true => -((c.gpu_tick.wrapping_sub(tick) & mask) as f64),
            false => ahead as f64,
        };
        Some(c.host_ns as f64 + delta * f64::from(self.timestamp_period_ns))
    }
}

/// The device and driver a profile's passes ran on (the trace's metadata).
#[derive(Clone, Debug, Default, Serialize)]
pub struct ProfiledDevice {
    /// The device's name.
    pub device: String,
    /// The driver's name and version.
    pub driver: String,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// The bandwidth of the best plain copy kernel on this device (read plus written GiB
    /// per second), measured in the same run: what a pass's [`PassBytes`] is weighed
    /// against. `None` where nobody measured it.
    pub copy_gib_per_s: Option<f64>,
}

/// Every scope of one submission, in the order they were opened.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Profile {
    /// The scopes, in opening order; a scope's parent comes before it.
    pub passes: Vec<PassTime>,
    /// Scopes left without a time because the recorder's timestamp queries ran out (never
    /// silently: also logged as a warning).
    pub untimed_scopes: usize,
    /// The submissions the passes ran in, each with its host times and calibration.
    pub submissions: Vec<Submission>,
    /// What the host did meanwhile, recorded while a capture ([`capture`]) is active:
    /// recording, submits, waits, read-backs, uploads, builds on the CPU.
    pub host_spans: Vec<HostSpan>,
    /// The device the passes ran on.
    pub device: Option<ProfiledDevice>,
}

impl Profile {
    /// Whether scope `i` lies inside another scope of its own name (a dispatch scope named
    /// like the pass around it): its time is already in that scope's.
    fn inside_namesake(&self, i: usize) -> bool {
        let mut up = self.passes[i].parent;
        while let Some(a) = up {
            if self.passes[a].name == self.passes[i].name {
                return true;
            }
            up = self.passes[a].parent;
        }
        false
    }

    /// Total milliseconds of every scope called `name` (a scope inside another of the same
    /// name counted once, with the outer one).
    pub fn ms(&self, name: &str) -> Option<f64> {
        self.sum_named(name, |p| p.ms)
    }

    /// The sum of `value` over the scopes called `name` that lie in no scope of that name;
    /// `None` where none of them has a value.
    fn sum_named<T: std::iter::Sum<T>>(
        &self,
        name: &str,
        value: impl Fn(&PassTime) -> Option<T>,
    ) -> Option<T> {
        let values: Vec<T> = (0..self.passes.len())
            .filter(|&i| self.passes[i].name == name && !self.inside_namesake(i))
            .filter_map(|i| value(&self.passes[i]))
            .collect();
        (!values.is_empty()).then(|| values.into_iter().sum())
    }

    /// Milliseconds of the scopes called `name` inside each scope called `within`, summed
    /// per `within` scope, in order: e.g. one pass's time in every sample. A `within` scope
    /// without a timed `name` inside gives nothing.
    pub fn ms_within(&self, name: &str, within: &str) -> Vec<f64> {
        let mut sums: Vec<(usize, f64)> = Vec::new();
        for (i, p) in self.passes.iter().enumerate() {
            let (true, Some(ms)) = (p.name == name, p.ms) else {
                continue;
            };
            if self.inside_namesake(i) {
                continue;
            }
            let mut up = self.passes[i].parent;
            while let Some(a) = up {
                if self.passes[a].name == within {
                    match sums.last_mut() {
                        Some((owner, sum)) if *owner == a => *sum += ms,
                        _ => sums.push((a, ms)),
                    }
                    break;
                }
                up = self.passes[a].parent;
            }
        }
        sums.into_iter().map(|(_, ms)| ms).collect()
    }

    /// The profile without the scopes called `name` and everything inside them, e.g. the
    /// timed passes without the `warm-up` before them.
    pub fn without(&self, name: &str) -> Profile {
        let mut dropped = vec![false; self.passes.len()];
        let mut kept: Vec<Option<usize>> = vec![None; self.passes.len()];
        let mut passes = Vec::new();
        for (i, p) in self.passes.iter().enumerate() {
            dropped[i] = p.name == name || p.parent.is_some_and(|q| dropped[q]);
            if !dropped[i] {
                let mut p = p.clone();
                p.parent = p.parent.and_then(|q| kept[q]);
                kept[i] = Some(passes.len());
                passes.push(p);
            }
        }
        self.with_passes(passes)
    }

    /// The scopes nested inside the last scope called `name` (that scope included), e.g.
    /// the timed run after a warm-up run of the same passes.
    pub fn subtree(&self, name: &str) -> Profile {
        let Some(root) = self.passes.iter().rposition(|p| p.name == name) else {
            return Profile::default();
        };
        let inside = |mut i: usize| loop {
            if i == root {
                return true;
            }
            match self.passes[i].parent {
                Some(parent) => i = parent,
                None => return false,
            }
        };
        let kept: Vec<usize> = (0..self.passes.len()).filter(|&i| inside(i)).collect();
        let passes = kept
            .iter()
            .map(|&i| {
                let mut p = self.passes[i].clone();
                p.parent = p.parent.and_then(|q| kept.iter().position(|&k| k == q));
                p
            })
            .collect();
        self.with_passes(passes)
    }

    /// This profile with `passes` in place of its scopes (its submissions, host spans and
    /// device kept).
    fn with_passes(&self, passes: Vec<PassTime>) -> Profile {
        Profile {
            passes,
            untimed_scopes: self.untimed_scopes,
            submissions: self.submissions.clone(),
            host_spans: self.host_spans.clone(),
            device: self.device.clone(),
        }
    }

    /// Appends `other`'s scopes (e.g. several submissions of one command) after a gap, with
    /// its submissions and host spans.
    pub fn append(&mut self, other: Profile) {
        let offset = self.passes.len();
        let submissions = self.submissions.len();
        let shift = self
            .passes
            .iter()
            .filter_map(|p| Some(p.start_ms? + p.ms?))
            .fold(0.0, f64::max);
        self.untimed_scopes += other.untimed_scopes;
        for mut p in other.passes {
            p.parent = p.parent.map(|i| i + offset);
            p.start_ms = p.start_ms.map(|s| s + shift);
            p.submission = p.submission.map(|i| i + submissions);
            self.passes.push(p);
        }
        self.submissions.extend(other.submissions);
        self.host_spans.extend(other.host_spans);
        // The later record: a copy baseline measured after the first submission is in it.
        if other.device.is_some() {
            self.device = other.device;
        }
    }

    /// Compute-shader invocations of every scope called `name` (a scope inside another of
    /// the same name counted once, with the outer one); `None` where none was counted.
    pub fn invocations(&self, name: &str) -> Option<u64> {
        self.sum_named(name, |p| p.invocations)
    }

    /// The bytes every scope called `name` read and wrote (counted as
    /// [`Profile::invocations`]); `None` where none of them knows its bytes.
    pub fn bytes(&self, name: &str) -> Option<PassBytes> {
        self.sum_named(name, |p| p.bytes)
    }

    /// Scope `i`'s start and end on the host's clock (nanoseconds), where its submission is
    /// calibrated.
    pub fn host_interval_ns(&self, i: usize) -> Option<(f64, f64)> {
        let p = &self.passes[i];
        let [b, e] = p.ticks?;
        let s = self.submissions.get(p.submission?)?;
        Some((s.host_ns_of(b)?, s.host_ns_of(e)?))
    }

    /// The Chrome trace-event JSON (complete events, microseconds) that Perfetto opens: a
    /// CPU track of the host's spans and a GPU track per queue family, on one time axis
    /// (the host's clock, from the earliest event), with the device, the driver, the
    /// timestamp period and the calibration in `otherData`. Scopes of a profile without
    /// calibration (made by hand) keep their relative times on the GPU track.
    pub fn chrome_trace(&self) -> serde_json::Value {
        use serde_json::json;
        const PID: u32 = 1;
        const CPU_TID: u32 = 1;
        let gpu_tid = |family: u32| 100 + family;
        let mapped: Vec<Option<(f64, f64)>> = (0..self.passes.len())
            .map(|i| self.host_interval_ns(i))
            .collect();
        let origin = self
            .host_spans
            .iter()
            .map(|h| h.start_ns as f64)
            .chain(self.submissions.iter().map(|s| s.submitted_ns as f64))
            .chain(mapped.iter().flatten().map(|m| m.0))
            .fold(f64::INFINITY, f64::min);
        let origin = if origin.is_finite() { origin } else { 0.0 };
        let us = |ns: f64| (ns - origin) / 1000.0;
        let mut events = vec![
            json!({"name": "process_name", "ph": "M", "pid": PID, "tid": CPU_TID, "args": {"name": "vkrt"}}),
            json!({"name": "thread_name", "ph": "M", "pid": PID, "tid": CPU_TID, "args": {"name": "CPU (host thread)"}}),
            json!({"name": "thread_sort_index", "ph": "M", "pid": PID, "tid": CPU_TID, "args": {"sort_index": 0}}),
        ];
        let mut families: Vec<u32> = self.submissions.iter().map(|s| s.queue_family).collect();
        if families.is_empty() {
            families.push(0);
        }
        families.sort_unstable();
        families.dedup();
        for &f in &families {
            events.push(json!({"name": "thread_name", "ph": "M", "pid": PID, "tid": gpu_tid(f), "args": {"name": format!("GPU queue family {f}")}}));
            events.push(json!({"name": "thread_sort_index", "ph": "M", "pid": PID, "tid": gpu_tid(f), "args": {"sort_index": 1 + f}}));
        }
        let mut spans = Vec::new();
        for h in &self.host_spans {
            spans.push(json!({
                "name": h.name, "cat": "host", "ph": "X", "pid": PID, "tid": CPU_TID,
                "ts": us(h.start_ns as f64), "dur": (h.end_ns.saturating_sub(h.start_ns)) as f64 / 1000.0,
            }));
        }
        for (p, m) in self.passes.iter().zip(&mapped) {
            let (ts, dur) = match (m, p.start_ms, p.ms) {
                (Some((b, e)), _, _) => (us(*b), (e - b) / 1000.0),
                (None, Some(start), Some(ms)) => (start * 1000.0, ms * 1000.0),
                _ => continue,
            };
            let family = p
                .submission
                .and_then(|i| self.submissions.get(i))
                .map_or(families[0], |s| s.queue_family);
            let mut args = json!({"depth": p.depth, "kind": p.kind});
            if let Some(n) = p.invocations {
                args["compute_invocations"] = json!(n);
            }
            if let Some(t) = p.bytes.filter(|t| t.total() > 0) {
                args["read_bytes"] = json!(t.read);
                args["written_bytes"] = json!(t.written);
                if let Some(ms) = p.ms.filter(|&ms| ms > 0.0) {
                    let gib = t.gib_per_s(ms);
                    args["gib_per_s"] = json!(gib);
                    if let Some(copy) = self.device.as_ref().and_then(|d| d.copy_gib_per_s) {
                        args["of_copy_bandwidth"] = json!(gib / copy);
                    }
                }
            }
            spans.push(json!({
                "name": p.name, "cat": "gpu", "ph": "X", "pid": PID, "tid": gpu_tid(family),
                "ts": ts, "dur": dur, "args": args,
            }));
        }
        // Earlier first, and of two starting together the longer (the enclosing) first.
        spans.sort_by(|a, b| {
            let key = |e: &serde_json::Value| {
                (
                    e["ts"].as_f64().unwrap_or(0.0),
                    -e["dur"].as_f64().unwrap_or(0.0),
                )
            };
            key(a)
                .partial_cmp(&key(b))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        events.extend(spans);
        let calibrations: Vec<&Calibration> = self
            .submissions
            .iter()
            .filter_map(|s| s.calibration.as_ref())
            .collect();
        let mut methods: Vec<&str> = calibrations.iter().map(|c| c.method).collect();
        methods.sort_unstable();
        methods.dedup();
        let deviation = calibrations.iter().filter_map(|c| c.max_deviation_ns).max();
        let device = self.device.clone().unwrap_or_default();
        json!({
            "traceEvents": events,
            "displayTimeUnit": "ms",
            "otherData": {
                "device": device.device,
                "driver": device.driver,
                "timestamp_period_ns": device.timestamp_period_ns,
                "copy_gib_per_s": device.copy_gib_per_s,
                "calibration": methods.join(", "),
                "calibration_max_deviation_ns": deviation,
                "submissions": self.submissions.len(),
                "untimed_scopes": self.untimed_scopes,
                "time_origin_ns": origin,
            },
        })
    }

    /// Writes [`Profile::chrome_trace`] to `path` atomically: a failed write leaves no file.
    pub fn write_chrome_trace(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(&self.chrome_trace()).expect("JSON of plain data");
        write_atomically(path, text.as_bytes())
    }
}

/// Count, median and range of repeated measurements (e.g. one pass over the samples).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// How many measurements.
    pub count: usize,
    /// Their median (the mean of the middle two for an even count).
    pub median: f64,
    /// The smallest.
    pub min: f64,
    /// The largest.
    pub max: f64,
}

impl Spread {
    /// The spread of `values` (all zero when there are none).
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = match n % 2 {
            1 => v[n / 2],
            _ => (v[n / 2 - 1] + v[n / 2]) / 2.0,
        };
        Self {
            count: n,
            median,
            min: v[0],
            max: v[n - 1],
        }
    }
}

thread_local! {
    static CAPTURE: std::cell::RefCell<Option<Profile>> = const { std::cell::RefCell::new(None) };
}

/// Runs `f` and returns, with its result, the profiles of every submission this thread
/// completed meanwhile, one after another, and the host spans it recorded — how the CLI's
/// `--profile` covers whole commands.
pub fn capture<R>(f: impl FnOnce() -> R) -> (R, Profile) {
    let outer = CAPTURE.with(|c| c.borrow_mut().replace(Profile::default()));
    let result = f();
    let captured = CAPTURE
        .with(|c| std::mem::replace(&mut *c.borrow_mut(), outer))
        .unwrap_or_default();
    if let Some(p) = CAPTURE.with(|c| c.borrow().is_some().then(|| captured.clone())) {
        record_captured(&p);
    }
    (result, captured)
}

/// Adds a host span to the active capture, if any.
pub(crate) fn record_host_span(span: HostSpan) {
    CAPTURE.with(|c| {
        if let Some(active) = c.borrow_mut().as_mut() {
            active.host_spans.push(span);
        }
    });
}

/// Adds a completed submission's profile to the active capture, if any.
pub(crate) fn record_captured(profile: &Profile) {
    CAPTURE.with(|c| {
        if let Some(active) = c.borrow_mut().as_mut() {
            active.append(profile.clone());
        }
    });
}

/// Writes a file through a temporary sibling and a rename, so readers never see a partial
/// file and a failure leaves nothing behind.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |e: std::io::Error| GpuError::Io {
        path: path.display().to_string(),
        reason: e.to_string(),
    };
    let file_name = path.file_name().ok_or_else(|| GpuError::Io {
        path: path.display().to_string(),
        reason: "not a file path".into(),
    })?;
    let tmp = path.with_file_name(format!(
        ".{}.tmp{}",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let result = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

/// Creates a timestamp query pool when the device supports timestamps.
pub(crate) fn create_query_pool(
    device: &ash::Device,
    capacity: u32,
    timestamps: bool,
) -> Result<Option<vk::QueryPool>> {
    if !timestamps || capacity == 0 {
        return Ok(None);
    }
    let info = vk::QueryPoolCreateInfo::default()
        .query_type(vk::QueryType::TIMESTAMP)
        .query_count(capacity);
    // SAFETY: valid device and create-info.
    let pool =
        unsafe { device.create_query_pool(&info, None) }.map_err(vk_err("vkCreateQueryPool"))?;
    Ok(Some(pool))
}

#[cfg(test)]
mod tests {
    use super::{Calibration, PassTime, Profile, Submission};

    fn submission(valid_bits: u32, gpu_tick: u64, period: f32) -> Submission {
        Submission {
            queue_family: 2,
            submitted_ns: 1_000,
            completed_ns: 9_000,
            timestamp_period_ns: period,
            valid_bits,
            calibration: Some(Calibration {
                method: "VK_KHR_calibrated_timestamps",
                gpu_tick,
                host_ns: 5_000,
                max_deviation_ns: Some(10),
            }),
        }
    }

    #[test]
    fn ticks_map_onto_the_host_clock_across_a_wrap_of_the_valid_bits() {
        let s = submission(36, 10, 2.0);
        assert_eq!(s.host_ns_of(10), Some(5_000.0));
        assert_eq!(s.host_ns_of(110), Some(5_200.0));
        // 20 ticks before the calibration's, on the far side of the 36-bit wrap.
        let before = (1u64 << 36) - 10;
        assert_eq!(s.host_ns_of(before), Some(4_960.0));
        let s = submission(64, u64::MAX - 4, 1.0);
        assert_eq!(s.host_ns_of(5), Some(5_010.0));
        assert_eq!(Submission::default().host_ns_of(5), None);
    }

    #[test]
    fn appended_profiles_keep_each_scope_with_its_submission() {
        let one = |name: &str, tick: u64| Profile {
            passes: vec![PassTime {
                name: name.into(),
                start_ms: Some(0.0),
                ms: Some(0.1),
                ticks: Some([tick, tick + 100]),
                submission: Some(0),
                ..PassTime::default()
            }],
            submissions: vec![submission(64, tick, 1.0)],
            ..Profile::default()
        };
        let mut p = one("a", 1_000);
        p.append(one("b", 7_000));
        assert_eq!(p.passes[1].submission, Some(1));
        assert_eq!(p.host_interval_ns(0), Some((5_000.0, 5_100.0)));
        assert_eq!(p.host_interval_ns(1), Some((5_000.0, 5_100.0)));
        let trace = p.chrome_trace();
        let events = trace["traceEvents"].as_array().unwrap();
        let gpu: Vec<_> = events
            .iter()
            .filter(|e| e["ph"] == "X" && e["tid"] == 102)
            .collect();
        assert_eq!(gpu.len(), 2);
        assert_eq!(gpu[0]["dur"], 0.1);
        assert!(events
            .iter()
            .any(|e| e["ph"] == "M" && e["args"]["name"] == "GPU queue family 2"));
        assert_eq!(
            trace["otherData"]["calibration"],
            "VK_KHR_calibrated_timestamps"
        );
        assert_eq!(trace["otherData"]["calibration_max_deviation_ns"], 10);
    }
}
