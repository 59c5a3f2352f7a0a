//! GPU pass timing: timestamp queries around nested named scopes, read back after the
//! submission completes and turned into per-pass milliseconds via `timestampPeriod`.
//!
//! The same name is the debug-utils label (RenderDoc, Nsight, validation messages) and the
//! crash marker reported on `DEVICE_LOST`. `Profile::write_chrome_trace` exports the
//! Chrome trace-event JSON that Perfetto (ui.perfetto.dev) and chrome://tracing open.

use std::path::Path;

use ash::vk;
use serde::Serialize;

use super::error::{vk_err, GpuError, Result};

/// Timestamp queries one recorder reserves by default (two per scope).
pub const DEFAULT_QUERY_CAPACITY: u32 = 32768;

#[derive(Debug)]
struct Scope {
    name: String,
    depth: u32,
    parent: Option<usize>,
    begin: Option<u32>,
    end: Option<u32>,
}

/// The recording side: hands out query indices and remembers the scope tree.
pub(crate) struct ScopeRecorder {
    pub(crate) pool: Option<vk::QueryPool>,
    capacity: u32,
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
            pool,
            capacity,
            next_query: 0,
            scopes: Vec::new(),
            open: Vec::new(),
            unmatched_ends: 0,
            untimed: 0,
        }
    }

    fn take_query(&mut self) -> Option<u32> {
        (self.pool.is_some() && self.next_query < self.capacity).then(|| {
            self.next_query += 1;
            self.next_query - 1
        })
    }

    /// Opens a scope; returns the query to write a timestamp into, if any.
    pub(crate) fn begin(&mut self, name: &str) -> Option<u32> {
        let begin = self.take_query();
        if begin.is_none() && self.pool.is_some() {
            self.untimed += 1;
        }
        self.scopes.push(Scope {
            name: name.to_string(),
            depth: self.open.len() as u32,
            parent: self.open.last().copied(),
            begin,
            end: None,
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
            self.take_query()
        } else {
            None
        };
        self.scopes[index].end = end;
        end
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
                let timed = match (s.begin, s.end) {
                    (Some(b), Some(e)) => {
                        let (b, e) = (ticks[b as usize] & mask, ticks[e as usize] & mask);
                        Some((
                            to_ms(b),
                            (e.wrapping_sub(b) & mask) as f64 * f64::from(period_ns) / 1e6,
                        ))
                    }
                    _ => None,
                };
                PassTime {
                    name: s.name.clone(),
                    depth: s.depth,
                    parent: s.parent,
                    start_ms: timed.map(|t| t.0),
                    ms: timed.map(|t| t.1),
                }
            })
            .collect();
        if self.untimed > 0 {
            log::warn!(
                "{} of {} scopes untimed: the recorder's {} timestamp queries ran out \
                 (Recorder::from_raw takes the count)",
                self.untimed,
                self.scopes.len(),
                self.capacity
            );
        }
        Profile {
            passes,
            untimed_scopes: self.untimed,
        }
    }

    /// The scope tree without times (no timestamp support).
    pub(crate) fn untimed(&self) -> Profile {
        debug_assert_eq!(self.next_query, 0);
        self.resolve(&[], 1.0, 64)
    }
}

/// One scope's timing. `None` times mean the device has no timestamps or the query
/// capacity ran out.
#[derive(Clone, Debug, Serialize)]
pub struct PassTime {
    /// The scope's name (also its debug-utils label).
    pub name: String,
    /// Nesting depth: 0 for an outermost scope.
    pub depth: u32,
    /// Index of the enclosing scope in `Profile::passes`.
    pub parent: Option<usize>,
    /// Start, in milliseconds after the earliest timed scope of the submission began.
    pub start_ms: Option<f64>,
    /// Duration in milliseconds.
    pub ms: Option<f64>,
}

/// Every scope of one submission, in the order they were opened.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Profile {
    /// The scopes, in opening order; a scope's parent comes before it.
    pub passes: Vec<PassTime>,
    /// Scopes left without a time because the recorder's timestamp queries ran out (never
    /// silently: also logged as a warning).
    pub untimed_scopes: usize,
}

impl Profile {
    /// Total milliseconds of every scope called `name`.
    pub fn ms(&self, name: &str) -> Option<f64> {
        let times: Vec<f64> = self
            .passes
            .iter()
            .filter(|p| p.name == name)
            .filter_map(|p| p.ms)
            .collect();
        (!times.is_empty()).then(|| times.iter().sum())
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
        Profile {
            passes,
            untimed_scopes: self.untimed_scopes,
        }
    }

    /// Appends `other`'s scopes (e.g. several submissions of one command) after a gap.
    pub fn append(&mut self, other: Profile) {
        let offset = self.passes.len();
        let shift = self
            .passes
            .iter()
            .filter_map(|p| Some(p.start_ms? + p.ms?))
            .fold(0.0, f64::max);
        self.untimed_scopes += other.untimed_scopes;
        for mut p in other.passes {
            p.parent = p.parent.map(|i| i + offset);
            p.start_ms = p.start_ms.map(|s| s + shift);
            self.passes.push(p);
        }
    }

    /// The Chrome trace-event JSON (complete events, microseconds) that Perfetto opens.
    pub fn chrome_trace(&self) -> serde_json::Value {
        let mut events = vec![
            serde_json::json!({"name": "process_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "vkrt GPU"}}),
            serde_json::json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "queue"}}),
        ];
        for p in &self.passes {
            if let (Some(start), Some(ms)) = (p.start_ms, p.ms) {
                events.push(serde_json::json!({
                    "name": p.name, "cat": "gpu", "ph": "X", "pid": 1, "tid": 1,
                    "ts": start * 1000.0, "dur": ms * 1000.0, "args": {"depth": p.depth},
                }));
            }
        }
        serde_json::json!({ "traceEvents": events, "displayTimeUnit": "ms" })
    }

    /// Writes [`Profile::chrome_trace`] to `path` atomically: a failed write leaves no file.
    pub fn write_chrome_trace(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(&self.chrome_trace()).expect("JSON of plain data");
        write_atomically(path, text.as_bytes())
    }
}

thread_local! {
    static CAPTURE: std::cell::RefCell<Option<Profile>> = const { std::cell::RefCell::new(None) };
}

/// Runs `f` and returns, with its result, the profiles of every submission this thread
/// completed meanwhile, one after another — how the CLI's `--profile` covers whole commands.
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
