//! `vkrt bench history`: one fixed quick set measured in one process — every walk tracing
//! one mesh's primary rays, the driver's ray query where the device has it, the GPU builds
//! (kd-tree, LBVH, PLOC), the chained scan and, where a [`QueryShader`] is given, a
//! renderer's `GL_EXT_ray_query` shader through `vkrt/ext_ray_query.glsl` on the same rays —
//! each as a ratio to the best copy kernel's time for as many bytes, measured in the same
//! run, so that the machine's speed cancels and a run can be set against an earlier one
//! ([`compare`]). Every ratio is a time over a time: lower is better.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

use vkrt::accel::device::AccelKind;
use vkrt::accel::walk::{AccelChoice, NodeAccess, Traversal};
use vkrt::gpu::{Buffer, Context, GpuError, Recorder, Result};
use vkrt::prims::scan::{Scan, ScanInput, ScanOp};
use vkrt::prims::PrimConfig;
use vkrt::shader_check::levels::SceneLevels;
use vkrt::shader_check::reflect::ShaderInterface;
use vkrt::shader_check::{self as check, Through};

use super::copy::copy_baselines;
use super::{best_ms, rep_scope};
use crate::trace_bench::{best_build, best_trace, structures, BenchScene, RaySet};
use vkrt::accel::driver::Prefer;

/// The version of a history line's layout.
pub const SCHEMA: u32 = 1;

/// Bytes a traced ray moves at least: the ray in (8 floats) and its hit out (4 words).
const BYTES_PER_RAY: u64 = 48;
/// Traces of each walk in each round of [`measure`] (a trace is short: more repetitions
/// cost little and steady its best).
const TRACE_REPS: u32 = 3;
/// Bytes a triangle's input holds (three vertices of three floats).
const BYTES_PER_TRIANGLE: u64 = 36;

/// What the fixed set measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HistoryOptions {
    /// Width of the camera image in pixels, one primary ray per pixel.
    pub size: u32,
    /// Elements of the scan (u32); the copy baseline moves `4 * scan_n` bytes.
    pub scan_n: u64,
    /// Rounds of the whole set; each item keeps its best over the rounds.
    pub reps: u32,
}

impl Default for HistoryOptions {
    fn default() -> Self {
        Self {
            size: 128,
            scan_n: 1 << 22,
            reps: 5,
        }
    }
}

/// The set a run measured: only runs of the same set (and device and driver) are compared.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunSet {
    /// The mesh's name (`bunny`, `icosphere100k`, ...).
    pub scene: String,
    /// Its triangles.
    pub triangles: u64,
    /// Primary rays traced (the camera image's pixels).
    pub rays: u64,
    /// The measurement's sizes and repetitions.
    pub options: HistoryOptions,
}

/// The run's baseline: the fastest plain copy kernel over `bytes`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CopyBaseline {
    /// The copy kernel's name (`copy_kernel.<granule>.wg<size>`).
    pub kernel: String,
    /// Bytes it copied (read, and as many written).
    pub bytes: u64,
    /// Its best time, milliseconds.
    pub ms: f64,
}

impl CopyBaseline {
    /// The copy's time scaled to `bytes` (copies are bandwidth-bound: linear in bytes).
    pub fn ms_for(&self, bytes: u64) -> f64 {
        self.ms * bytes as f64 / self.bytes as f64
    }
}

/// One measured figure and its ratio.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metric {
    /// Best time, milliseconds.
    pub ms: f64,
    /// What it is set against, milliseconds, from the same run.
    pub baseline_ms: f64,
    /// `ms / baseline_ms`: lower is better.
    pub ratio: f64,
}

impl Metric {
    fn new(ms: f64, baseline_ms: f64) -> Self {
        Self {
            ms,
            baseline_ms,
            ratio: ms / baseline_ms,
        }
    }
}

/// One line of the history file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct HistoryRun {
    /// [`SCHEMA`].
    pub schema: u32,
    /// When it ran, UTC, `YYYY-MM-DDTHH:MM:SSZ`.
    pub date: String,
    /// The checkout's commit (`git rev-parse --short=12 HEAD`; `None` outside a checkout),
    /// with `-dirty` where it had uncommitted changes.
    pub commit: Option<String>,
    /// The device name the driver reports.
    pub device: String,
    /// The driver's name and version.
    pub driver: String,
    /// What was measured.
    pub set: RunSet,
    /// The baseline every metric but `trace.best_over_driver` is set against.
    pub copy: CopyBaseline,
    /// By name (see the module docs and docs/cli.md), in name order.
    pub metrics: BTreeMap<String, Metric>,
}

/// The ray-query part of the set (`query.*`): a renderer's opaque closest-hit
/// `GL_EXT_ray_query` shader in `vkrt shader-check`'s interface, compiled once through the
/// include and, where the device has ray query, for the driver's own.
pub struct QueryShader {
    vkrt: (Vec<u32>, ShaderInterface),
    native: Option<(Vec<u32>, ShaderInterface)>,
}

impl QueryShader {
    /// Compiles `path` (glslc, or the program `VKRT_GLSLC` names) with vkrt's include files,
    /// and also for the driver's ray query where `native`.
    pub fn compile(path: &Path, native: bool) -> std::result::Result<Self, String> {
        let source = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read the shader: {e}", path.display()))?;
        let include = check::compile::TempDir::new("history-include").map_err(|e| e.to_string())?;
        vkrt::accel::shader_library::write_to(include.path()).map_err(|e| e.to_string())?;
        let through = if native { Through::Both } else { Through::Vkrt };
        let compiled = check::compile_shader(path, &source, include.path(), through)
            .map_err(|e| e.to_string())?;
        Ok(Self {
            vkrt: compiled.vkrt.expect("compiled through vkrt"),
            native: compiled.native,
        })
    }
}

/// Measures the fixed set over `scene` (see the module docs); `date` and `commit` are the
/// caller's. The repetitions are rounds, each measuring every item once (a trace
/// three times), and each item keeps its best over the rounds: a burst of other
/// work on a shared machine slows one round of everything rather than every repetition of
/// one item, and the copy baseline is measured in every round alike.
pub fn measure(
    ctx: &Context,
    scene: &BenchScene,
    opt: &HistoryOptions,
    mut query: Option<&QueryShader>,
) -> Result<HistoryRun> {
    let g = &scene.geometry;
    let triangles = g.triangle_count() as u64;
    let set = RaySet {
        kind: crate::trace_bench::RayKind::Primary,
        rays: scene.primary_rays(opt.size),
    };
    let rays = set.rays.len() as u64;
    let access = NodeAccess::for_device(ctx);
    let structures: Vec<_> = structures(ctx)
        .into_iter()
        .filter(|(s, _)| !(s.kind == AccelKind::Driver && s.prefer == Prefer::FastBuild))
        .collect();
    let mut copy: Option<CopyBaseline> = None;
    let mut scan_ms = f64::INFINITY;
    // (name, best ms) of the builds and of the traces, in the order measured.
    let mut builds: Vec<(&str, f64)> = Vec::new();
    let mut traces: Vec<(AccelChoice, f64)> = Vec::new();
    // The query's two levels: the mesh as one instance over an SAH BVH bottom level walked
    // the device's way; (include, driver) best ms.
    let levels = query.map(|_| {
        let tris: Vec<_> = (0..g.triangle_count())
            .map(|i| g.triangle_at(i, 0.0))
            .collect();
        SceneLevels::of_triangles(&tris)
    });
    let query_choice = AccelChoice::new(AccelKind::SahBvh, Traversal::for_device(ctx));
    let (mut include_ms, mut query_driver_ms) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..opt.reps.max(1) {
        let c = best_copy(ctx, 4 * opt.scan_n.max(32), 1)?;
        scan_ms = scan_ms.min(self::scan_ms(ctx, (c.bytes / 4) as usize, 1)?);
        if copy.as_ref().is_none_or(|best| c.ms < best.ms) {
            copy = Some(c);
        }
        for (structure, walks) in &structures {
            let (geom, build_ms) = best_build(ctx, *structure, g, 1)?;
            let gpu_built = matches!(
                structure.kind,
                AccelKind::KdTree | AccelKind::Lbvh | AccelKind::Ploc
            );
            if gpu_built && structure.walk != Traversal::Wide {
                keep_best(&mut builds, structure.kind.name(), build_ms);
            }
            for &walk in walks {
                let (_, ms, _) = best_trace(ctx, walk, access, &geom, &set, TRACE_REPS)?;
                keep_best(&mut traces, walk, ms);
            }
        }
        if let (Some(q), Some(levels)) = (query, &levels) {
            let (words, iface) = &q.vkrt;
            let run = match check::run_vkrt(ctx, levels, query_choice, (words, iface), &set.rays) {
                Ok(run) => run,
                // (a device the include cannot run on: the set goes on without it)
                Err(e @ GpuError::MissingCapability { .. }) => {
                    log::warn!("no query.* metrics: {e}");
                    query = None;
                    continue;
                }
                Err(e) => return Err(e),
            };
            include_ms = include_ms.min(run.ms.unwrap_or(f64::INFINITY));
            if let Some((words, iface)) = &q.native {
                let native = check::run_driver(ctx, levels, (words, iface), &set.rays)?;
                query_driver_ms = query_driver_ms.min(native.ms.unwrap_or(f64::INFINITY));
                let differ = check::mismatches(&native.results, &run.results).len();
                if differ > 0 {
                    log::warn!("the ray-query shader: {differ} rays differ from the driver's");
                }
            }
        }
    }
    let copy = copy.expect("at least one round");

    let mut metrics = BTreeMap::new();
    metrics.insert("scan.u32".into(), Metric::new(scan_ms, copy.ms));
    let build_base = copy.ms_for(triangles * BYTES_PER_TRIANGLE);
    for (kind, ms) in builds {
        metrics.insert(format!("build.{kind}"), Metric::new(ms, build_base));
    }
    let trace_base = copy.ms_for(rays * BYTES_PER_RAY);
    let (mut vkrt_best, mut driver_ms) = (f64::INFINITY, None);
    for (walk, ms) in traces {
        metrics.insert(
            format!("trace.{}", walk.label()),
            Metric::new(ms, trace_base),
        );
        if walk.kind == AccelKind::Driver {
            driver_ms = Some(ms);
        } else {
            vkrt_best = vkrt_best.min(ms);
        }
    }
    metrics.insert("trace.best".into(), Metric::new(vkrt_best, trace_base));
    if let Some(d) = driver_ms {
        metrics.insert("trace.best_over_driver".into(), Metric::new(vkrt_best, d));
    }
    if include_ms.is_finite() {
        metrics.insert("query.include".into(), Metric::new(include_ms, trace_base));
        if query_driver_ms.is_finite() {
            metrics.insert(
                "query.driver".into(),
                Metric::new(query_driver_ms, trace_base),
            );
            metrics.insert(
                "query.include_over_driver".into(),
                Metric::new(include_ms, query_driver_ms),
            );
        }
    }
    Ok(HistoryRun {
        schema: SCHEMA,
        date: String::new(),
        commit: None,
        device: ctx.info().device.clone(),
        driver: ctx.info().driver.clone(),
        set: RunSet {
            scene: scene.name.clone(),
            triangles,
            rays,
            options: *opt,
        },
        copy,
        metrics,
    })
}

/// Sets `key`'s entry in `list` to the smaller of it and `ms`, adding it where missing.
fn keep_best<K: PartialEq>(list: &mut Vec<(K, f64)>, key: K, ms: f64) {
    match list.iter_mut().find(|(k, _)| *k == key) {
        Some((_, best)) => *best = best.min(ms),
        None => list.push((key, ms)),
    }
}

/// The fastest plain copy kernel over `bytes`, best of `reps`.
fn best_copy(ctx: &Context, bytes: u64, reps: u32) -> Result<CopyBaseline> {
    let (baselines, _) = copy_baselines(ctx, bytes, reps)?;
    let best = baselines
        .best_kernel()
        .expect("every device runs the u32 copy kernel");
    Ok(CopyBaseline {
        kernel: best.method.clone(),
        bytes: best.bytes,
        ms: best.gpu_ms,
    })
}

/// The best time of the default scan (the chained scan, exclusive, u32) over `n` elements.
fn scan_ms(ctx: &Context, n: usize, reps: u32) -> Result<f64> {
    let scan = Scan::new(ctx, PrimConfig::default_for(ctx), ScanInput::U32)?;
    let words = Buffer::<u32>::new(ctx, "history.scan.in", n)?;
    let out = Buffer::<u32>::new(ctx, "history.scan.out", n)?;
    let scratch = scan.scratch(ctx, n)?;
    let mut rec = Recorder::new(ctx)?;
    rec.fill(&words, 1);
    rec.fill(&out, 0);
    rec.transfer_to_compute();
    for rep in 0..=reps {
        rec.scope(&rep_scope(rep, "scan"), |rec| {
            scan.record(rec, &words, &out, n, ScanOp::Exclusive, &scratch)
        });
        rec.compute_to_compute();
    }
    let profile = rec.submit_and_wait()?;
    Ok(best_ms(&profile, "scan"))
}

/// Why a history cannot be compared.
#[derive(Debug, PartialEq)]
pub enum HistoryError {
    /// No line at all.
    Empty,
    /// A line that is not a run (1-based line number, what is wrong).
    Malformed {
        /// Its number, from 1.
        line: usize,
        /// What the JSON reader said.
        message: String,
    },
    /// No earlier run of the newest one's device, driver and set.
    NoPrevious {
        /// The newest run's device.
        device: String,
        /// The newest run's driver.
        driver: String,
    },
}

impl fmt::Display for HistoryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HistoryError::Empty => write!(f, "the history holds no run"),
            HistoryError::Malformed { line, message } => {
                write!(f, "line {line} is not a benchmark run: {message}")
            }
            HistoryError::NoPrevious { device, driver } => write!(
                f,
                "no earlier run of the same set on {device} ({driver}) to compare the newest with"
            ),
        }
    }
}

impl std::error::Error for HistoryError {}

/// Every run in a history file's text, one JSON object a line (blank lines skipped).
pub fn parse(text: &str) -> std::result::Result<Vec<HistoryRun>, HistoryError> {
    let runs = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let run: HistoryRun = serde_json::from_str(l).map_err(|e| HistoryError::Malformed {
                line: i + 1,
                message: e.to_string(),
            })?;
            if run.schema != SCHEMA {
                return Err(HistoryError::Malformed {
                    line: i + 1,
                    message: format!("schema {} (this vkrt reads {SCHEMA})", run.schema),
                });
            }
            Ok(run)
        })
        .collect::<std::result::Result<Vec<_>, _>>()?;
    if runs.is_empty() {
        return Err(HistoryError::Empty);
    }
    Ok(runs)
}

/// One metric's change from the previous run to the newest.
#[derive(Clone, Debug, Serialize)]
pub struct Change {
    /// The metric's name.
    pub name: String,
    /// The previous run's ratio (`None`: not measured then).
    pub previous: Option<f64>,
    /// The newest run's ratio (`None`: not measured now).
    pub newest: Option<f64>,
    /// `newest / previous - 1` of the ratios (positive: slower).
    pub change: Option<f64>,
    /// `newest / previous - 1` of the times themselves.
    pub ms_change: Option<f64>,
    /// Whether it got worse by more than the threshold: its ratio and its time both.
    pub regressed: bool,
}

/// The newest run against the previous one of the same device, driver and set.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// The device both runs measured.
    pub device: String,
    /// Its driver.
    pub driver: String,
    /// The previous run's date and commit.
    pub previous: (String, Option<String>),
    /// The newest run's date and commit.
    pub newest: (String, Option<String>),
    /// The threshold, a fraction (0.1: 10 % worse).
    pub threshold: f64,
    /// Every metric of either run, in name order.
    pub changes: Vec<Change>,
}

impl Comparison {
    /// The metrics that got worse by more than the threshold.
    pub fn regressions(&self) -> Vec<&Change> {
        self.changes.iter().filter(|c| c.regressed).collect()
    }
}

/// Compares the last run in `runs` with the latest earlier one of the same device, driver
/// and set. A metric regressed where its ratio and its time both grew by more than
/// `threshold` (a fraction): a busier machine slows the baseline with the work, so the ratio
/// holds, and a baseline measured faster than before raises every ratio at once while no
/// time grew; neither is a regression of the code.
pub fn compare(
    runs: &[HistoryRun],
    threshold: f64,
) -> std::result::Result<Comparison, HistoryError> {
    let (newest, earlier) = runs.split_last().ok_or(HistoryError::Empty)?;
    let previous = earlier
        .iter()
        .rev()
        .find(|r| r.device == newest.device && r.driver == newest.driver && r.set == newest.set)
        .ok_or_else(|| HistoryError::NoPrevious {
            device: newest.device.clone(),
            driver: newest.driver.clone(),
        })?;
    let mut names: Vec<&String> = previous
        .metrics
        .keys()
        .chain(newest.metrics.keys())
        .collect();
    names.sort();
    names.dedup();
    let changes = names
        .into_iter()
        .map(|name| {
            let (old, new) = (previous.metrics.get(name), newest.metrics.get(name));
            let grew = |f: fn(&Metric) -> f64| old.zip(new).map(|(o, n)| f(n) / f(o) - 1.0);
            let change = grew(|m| m.ratio);
            let ms_change = grew(|m| m.ms);
            // NaN (0/0) is no evidence either way; infinity is a regression.
            let worse = |c: Option<f64>| c.is_some_and(|c| c > threshold);
            Change {
                name: name.clone(),
                previous: old.map(|m| m.ratio),
                newest: new.map(|m| m.ratio),
                change,
                ms_change,
                regressed: worse(change) && worse(ms_change),
            }
        })
        .collect();
    Ok(Comparison {
        device: newest.device.clone(),
        driver: newest.driver.clone(),
        previous: (previous.date.clone(), previous.commit.clone()),
        newest: (newest.date.clone(), newest.commit.clone()),
        threshold,
        changes,
    })
}

/// `secs` after the Unix epoch as `YYYY-MM-DDTHH:MM:SSZ` (Hinnant's days-to-civil).
pub fn utc_date(secs: u64) -> String {
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(device: &str, ratios: &[(&str, f64)]) -> HistoryRun {
        HistoryRun {
            schema: SCHEMA,
            date: "2026-01-01T00:00:00Z".into(),
            commit: Some("abc".into()),
            device: device.into(),
            driver: "Mesa 25".into(),
            set: RunSet {
                scene: "bunny".into(),
                triangles: 10,
                rays: 4,
                options: HistoryOptions::default(),
            },
            copy: CopyBaseline {
                kernel: "copy_kernel.u32.wg64".into(),
                bytes: 64,
                ms: 1.0,
            },
            metrics: ratios
                .iter()
                .map(|&(n, r)| (n.to_string(), Metric::new(r, 1.0)))
                .collect(),
        }
    }

    #[test]
    fn dates_are_civil_utc() {
        assert_eq!(utc_date(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_date(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_date(1_798_450_215), "2026-12-28T09:30:15Z");
    }

    #[test]
    fn compare_flags_only_what_got_worse_beyond_the_threshold() {
        let runs = [
            run("a", &[("scan.u32", 2.0), ("trace.best", 10.0)]),
            run("b", &[("scan.u32", 1.0)]),
            run(
                "a",
                &[("scan.u32", 2.1), ("trace.best", 12.0), ("build.lbvh", 3.0)],
            ),
        ];
        let c = compare(&runs, 0.1).unwrap();
        let names: Vec<_> = c.regressions().iter().map(|c| c.name.clone()).collect();
        assert_eq!(names, ["trace.best"]);
        assert_eq!(c.changes.len(), 3);
        assert!(c.changes[0].change.is_none(), "build.lbvh is new");
        assert!(compare(&runs, 0.25).unwrap().regressions().is_empty());
    }

    #[test]
    fn a_faster_baseline_alone_is_no_regression() {
        // Every ratio 35 % higher because the copy baseline measured faster, every time the
        // same: nothing regressed. Then one time 40 % longer as well: that one did.
        let before = run("a", &[("scan.u32", 2.0), ("trace.best", 10.0)]);
        let mut after = before.clone();
        for m in after.metrics.values_mut() {
            *m = Metric::new(m.ms, m.baseline_ms / 1.35);
        }
        let c = compare(&[before.clone(), after.clone()], 0.25).unwrap();
        assert!(c.regressions().is_empty());
        assert!(c.changes.iter().all(|c| c.change.unwrap() > 0.3));
        let slower = after.metrics["trace.best"].ms * 1.4;
        after.metrics.insert(
            "trace.best".into(),
            Metric::new(slower, after.metrics["trace.best"].baseline_ms),
        );
        let c = compare(&[before, after], 0.25).unwrap();
        let names: Vec<_> = c.regressions().iter().map(|c| c.name.clone()).collect();
        assert_eq!(names, ["trace.best"]);
    }

    #[test]
    fn compare_needs_an_earlier_run_of_the_same_device() {
        let runs = [run("a", &[]), run("b", &[])];
        assert!(matches!(
            compare(&runs, 0.1),
            Err(HistoryError::NoPrevious { .. })
        ));
        assert_eq!(compare(&[], 0.1).unwrap_err(), HistoryError::Empty);
    }

    #[test]
    fn parse_names_the_malformed_line() {
        let good = serde_json::to_string(&run("a", &[("scan.u32", 1.0)])).unwrap();
        assert_eq!(parse(&format!("{good}\n\n{good}\n")).unwrap().len(), 2);
        let err = parse(&format!("{good}\n{{\"schema\": 1}}\n")).unwrap_err();
        assert!(
            matches!(err, HistoryError::Malformed { line: 2, .. }),
            "{err}"
        );
        assert_eq!(parse("\n").unwrap_err(), HistoryError::Empty);
    }
}
