//! `vkrt bench accuracy`: what accuracy costs in time, every knob measured in one
//! run on one device against a reference, grouped, with each group's Pareto front and a
//! recommendation per use derived from the numbers.
//!
//! - [`knobs`]: the groups of settings (structures and their builders' parameters, kd-tree
//!   termination, BVH leaf size, traversal, intersector, samples per pixel, ray depth, refit
//!   vs rebuild after motion);
//! - [`measure`]: the costs and accuracies of each setting (build and trace ms on the
//!   bunny's primary, shadow and mirror rays, SAH cost, bytes, failures on the robustness
//!   suite's hard cases, image error against a converged reference);
//! - [`pareto`]: the fronts and the recommendations;
//! - [`report`]: `index.html` (inline SVG plots), `report.json` and the compared images.
//!
//! Every group has one time axis and one error axis (`KnobGroup::time_axis`,
//! `KnobGroup::error_axis`); a point is on the front when no other point of its group is at
//! most as slow and at most as wrong, and strictly better in one.

pub mod knobs;
pub mod measure;
pub mod pareto;
pub mod report;
mod table;

use serde::Serialize;

/// Everything one run measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct AccuracyReport {
    /// The device and its driver (name, version) as Vulkan reports them.
    pub device: String,
    /// The driver's name and info string.
    pub driver: String,
    /// The command line that produced the report.
    pub command: String,
    /// Whether the run was `--quick` (fewer settings, smaller sizes).
    pub quick: bool,
    /// Wall seconds of the whole run.
    pub wall_s: f64,
    /// The mesh whose rays time the structures, and how many rays of each kind.
    pub mesh: String,
    /// Rays of each kind traced through every structure setting.
    pub rays: RayCountsInfo,
    /// The robustness suite's sizes used for the hard cases (human-readable).
    pub hard_cases: String,
    /// The scenes images were compared on, with their references.
    pub image_scenes: Vec<ImageScene>,
    /// The knob groups, each with its measured settings and Pareto front.
    pub groups: Vec<KnobGroup>,
    /// The setting each use should pick in each group it matters for.
    pub recommendations: Vec<Recommendation>,
    /// What the run left out and why (e.g. the driver's structures without ray query).
    pub notes: Vec<String>,
}

/// How many rays of each kind time a structure.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RayCountsInfo {
    /// Primary rays (closest hit), one per pixel of the square ray image.
    pub primary: usize,
    /// Shadow rays from the primary hits (any hit).
    pub shadow: usize,
    /// Mirror rays from the primary hits (closest hit).
    pub secondary: usize,
}

/// A scene images are compared on.
#[derive(Clone, Debug, Serialize)]
pub struct ImageScene {
    /// `default` or the effect scene's file stem.
    pub name: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// The reference: this many samples per pixel, ray depth, on the watertight kd-tree.
    pub reference_spp: u32,
    /// The reference's ray depth (bounces).
    pub reference_depth: u32,
    /// The reference image's file in the report folder.
    pub reference_file: String,
}

/// One group of knobs: its settings measured, on one time axis and one error axis.
#[derive(Clone, Debug, Serialize)]
pub struct KnobGroup {
    /// Short id (`structure`, `kd-termination`, `bvh-leaf`, `traversal`, `intersector`,
    /// `spp`, `depth`, `refit`).
    pub id: String,
    /// Human-readable title (the plots' and recommendations' group name).
    pub title: String,
    /// What `Point::time_ms` is.
    pub time_axis: String,
    /// What `Point::error` is.
    pub error_axis: String,
    /// The error a preview tolerates on this group's axis (see [`pareto`]).
    pub preview_error_max: f64,
    /// Which uses the group's knobs matter for (names of [`pareto::USES`]).
    pub uses: Vec<String>,
    /// The group's settings, measured, in the order they were run.
    pub points: Vec<Point>,
    /// Indices into `points` on the Pareto front, fastest first.
    pub front: Vec<usize>,
}

/// One setting of a group, measured.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    /// The setting's label.
    pub setting: String,
    /// The group's time axis, milliseconds.
    pub time_ms: f64,
    /// The group's error axis.
    pub error: f64,
    /// What the setting costs, measured.
    pub costs: Costs,
    /// How wrong the setting is, measured.
    pub accuracy: Accuracy,
    /// What each use pays, where that is not `time_ms` (see [`UseTimes`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub use_times: Option<UseTimes>,
    /// Remarks on the measurement: what was left out (e.g. the driver's opaque structure has
    /// no SAH cost), rays out of traversal steps, or the motion group's frames and resolution.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The time each use pays for a structure setting, from the measured build and trace ms: a
/// preview rebuilds for every frame and traces one frame's rays (`build + trace`), a final
/// frame builds once and traces [`FINAL_FRAME_TRACES`] times as many rays
/// (`build + 256·trace`), and physics or visibility queries run against a structure built
/// once, so their cost is the trace alone. The recommendations rank by these.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct UseTimes {
    /// Interactive preview: `build + trace`, ms.
    pub preview_ms: f64,
    /// Final frame: `build + 256·trace`, ms.
    pub final_frame_ms: f64,
    /// Physics/visibility queries: `trace`, ms.
    pub queries_ms: f64,
}

/// How many times the bench's rays a final frame traces (e.g. 256 samples per pixel of
/// primary, shadow and bounce rays at the bench's resolution).
pub const FINAL_FRAME_TRACES: f64 = 256.0;

impl UseTimes {
    /// The use times of a setting that builds in `build_ms` and traces the bench's rays in
    /// `trace_ms`.
    pub fn new(build_ms: f64, trace_ms: f64) -> Self {
        Self {
            preview_ms: build_ms + trace_ms,
            final_frame_ms: build_ms + FINAL_FRAME_TRACES * trace_ms,
            queries_ms: trace_ms,
        }
    }

    /// The time of `use_case` (one of [`pareto::USES`]).
    pub fn of(&self, use_case: &str) -> f64 {
        match use_case {
            "interactive preview" => self.preview_ms,
            "final frame" => self.final_frame_ms,
            _ => self.queries_ms,
        }
    }
}

/// What a setting costs.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Costs {
    /// Build of the structure: GPU passes, or the host builder's wall time.
    pub build_ms: Option<f64>,
    /// Refit or rebuild per animation frame (the refit group).
    pub update_ms: Option<f64>,
    /// GPU trace kernel time of the bunny's rays, per kind.
    pub trace_ms: Option<TraceMs>,
    /// GPU time of the images' renders, summed over the image scenes.
    pub render_ms: Option<f64>,
    /// The structure's SAH cost (C_trav 1, C_isect 1.5, relative to the root box's area).
    pub sah_cost: Option<f64>,
    /// Device bytes of the structure.
    pub bytes: Option<u64>,
}

/// GPU trace ms of one ray set each.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct TraceMs {
    /// Primary rays (closest hit), ms.
    pub primary: f64,
    /// Shadow rays (any hit), ms.
    pub shadow: f64,
    /// Mirror rays (closest hit), ms.
    pub secondary: f64,
}

impl TraceMs {
    /// The three ray sets' ms, summed.
    pub fn total(&self) -> f64 {
        self.primary + self.shadow + self.secondary
    }
}

/// How wrong a setting is.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Accuracy {
    /// The robustness suite's hard cases.
    pub hard_cases: Option<HardCases>,
    /// Rays of the bunny whose answer differs from the reference setting's (hit or miss,
    /// primitive, `t` beyond 1e-5 relative).
    pub hit_differences: Option<u64>,
    /// Image error per compared scene.
    pub images: Vec<ImageError>,
    /// SAH cost over a fresh rebuild's (the refit group).
    pub sah_ratio: Option<f64>,
}

/// Failures on the hard cases, by kind.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct HardCases {
    /// Rays traced over all the hard cases.
    pub rays: u64,
    /// Rays that should hit and missed (watertightness).
    pub misses: u64,
    /// Re-hits of the spawning primitive (self-intersection).
    pub self_hits: u64,
    /// Answers that differ from brute force, wrong winners, hits of rays that must miss.
    pub wrong_hits: u64,
    /// Rays out of traversal steps, invalid structures, failed builds.
    pub errors: u64,
}

impl HardCases {
    /// All failures: misses, self-hits, wrong hits and errors.
    pub fn failures(&self) -> u64 {
        self.misses + self.self_hits + self.wrong_hits + self.errors
    }
}

/// One image against its reference, on display values (tone-mapped sRGB in [0, 1]).
#[derive(Clone, Debug, Serialize)]
pub struct ImageError {
    /// The compared scene's name (`ImageScene::name`).
    pub scene: String,
    /// Root-mean-square difference over every pixel's RGB channels.
    pub rmse: f64,
    /// The largest channel difference of any pixel.
    pub worst: f64,
    /// The image's file in the report folder.
    pub file: String,
}

/// The setting a use should pick in a group, and the numbers that say why.
#[derive(Clone, Debug, Serialize)]
pub struct Recommendation {
    /// One of [`pareto::USES`].
    pub use_case: String,
    /// The group's title.
    pub group: String,
    /// The recommended setting's label.
    pub setting: String,
    /// A sentence built from the measured numbers that says why.
    pub why: String,
}

/// An image the report writes: `file` in the report folder, 8-bit sRGB RGBA.
pub struct ImageFile {
    /// Path relative to the report folder (`images/<scene>/<name>.png`).
    pub file: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The pixels, row by row, 4 bytes each.
    pub rgba: Vec<u8>,
}
