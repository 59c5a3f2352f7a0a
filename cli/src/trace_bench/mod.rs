//! `vkrt bench trace`: ray throughput of every structure vkrt builds, walked
//! every way, against the driver's own ray tracing (`VK_KHR_ray_query`, where the device
//! has it) and a CPU peer (obvhs), on the same rays in one run.
//!
//! Per scene: every structure is built once per repetition (the best is reported: the GPU
//! passes of a device builder, from timestamps; the wall time of the host SAH BVH, on every
//! core; both of the driver's build preferences), then the primary rays of the scene's
//! camera (closest hit), shadow rays from their hits (any hit) and mirror reflections
//! (closest hit) are traced through it, best of `reps` GPU timestamps around the trace
//! kernel. The secondary rays start from the first structure's primary hits, so every
//! structure traces the same rays. Hit counts are compared with the first row, and a
//! difference is reported, not asserted: vkrt's structures share one watertight test and
//! must agree exactly; the driver's intersector and obvhs's Möller–Trumbore may differ by a
//! few rays that graze an edge.
//!
//! Mesa 25's lavapipe builds the driver's structure on the host by halving the primitives in
//! their input order (`lvp_build_internal_node`: no spatial sort, the build preference
//! ignored), so its trace speed follows the mesh's triangle order: fair on an icosphere
//! generated face by face, two orders of magnitude slower on the bunny's scan order.

mod obvhs_peer;
mod rays;
pub mod scenes;
mod table;

use serde::Serialize;

pub use obvhs_peer::ObvhsPeer;
pub use rays::{BenchScene, RayKind, RaySet, ShadowTarget};

use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::{NodeAccess, Traversal};
use vkrt::gpu::{Context, Result};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Query, TraceOptions};

/// How much to measure.
#[derive(Clone, Copy, Debug)]
pub struct BenchOptions {
    /// Width of the camera image in pixels (one primary ray per pixel).
    pub size: u32,
    /// Repetitions of each build and trace; the best is reported.
    pub reps: u32,
    /// How vkrt's walks read the structures: `None` the device's way
    /// ([`NodeAccess::for_device`]), one row per walk; `Some(both)` every walk through
    /// storage buffers and through texel buffers, two rows, their hits compared ray by ray.
    pub node_access: Option<AccessRows>,
}

/// Which node accesses [`BenchOptions::node_access`] measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum AccessRows {
    /// Storage buffers only.
    Storage,
    /// Texel buffers only.
    Texel,
    /// Both, storage first: the rows `WALK (storage)` and `WALK (texel)`.
    Both,
}

impl AccessRows {
    fn accesses(self) -> &'static [NodeAccess] {
        match self {
            AccessRows::Storage => &[NodeAccess::Storage],
            AccessRows::Texel => &[NodeAccess::Texel],
            AccessRows::Both => &[NodeAccess::Storage, NodeAccess::Texel],
        }
    }
}

impl BenchOptions {
    /// The node accesses these options measure on `ctx`, in row order.
    pub fn accesses_on(&self, ctx: &Context) -> Vec<NodeAccess> {
        match self.node_access {
            Some(rows) => rows.accesses().to_vec(),
            None => vec![NodeAccess::for_device(ctx)],
        }
    }
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            size: 512,
            reps: 3,
            node_access: None,
        }
    }
}

/// Who traced a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// A structure vkrt builds, walked by vkrt's kernels.
    Vkrt,
    /// The driver's structure, through its ray query.
    Driver,
    /// A CPU library, as a peer.
    CpuPeer,
}

/// Everything one run measured.
#[derive(Clone, Debug, Serialize)]
pub struct TraceBenchReport {
    /// The device name the driver reports.
    pub device: String,
    /// How vkrt's walks read the structures, in row order (`storage`, `texel`): the
    /// device's way, or both where asked.
    pub node_access: Vec<NodeAccess>,
    /// Whether the device has the driver's ray tracing (else no `driver` rows).
    pub ray_query: bool,
    /// Why the driver's rows are missing (`None` where they are present).
    pub driver_note: Option<String>,
    /// Width of the camera image in pixels ([`BenchOptions::size`]).
    pub size: u32,
    /// Repetitions of each build and trace (at least 1); the best is reported.
    pub reps: u32,
    /// One report per scene, in the order measured.
    pub scenes: Vec<SceneReport>,
}

/// One scene: its builds and its three ray sets.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// The scene's name.
    pub name: String,
    /// Triangles of the scene's geometry.
    pub triangles: usize,
    /// Spheres of the scene's geometry.
    pub spheres: usize,
    /// The camera image (`width` × `height` primary rays).
    pub width: u32,
    /// The camera image's height in pixels.
    pub height: u32,
    /// Where the shadow rays go.
    pub light: String,
    /// One row per structure built: vkrt's, the driver's, obvhs's.
    pub builds: Vec<BuildRow>,
    /// The primary, shadow and mirror ray sets, in that order.
    pub ray_sets: Vec<RaySetReport>,
}

/// One structure's build.
#[derive(Clone, Debug, Serialize)]
pub struct BuildRow {
    /// `kdtree`, `sah-bvh`, `driver/fast-build`, `obvhs`, ...
    pub structure: String,
    /// Who built it.
    pub backend: Backend,
    /// Best of the repetitions, milliseconds.
    pub ms: f64,
}

/// One ray set on one scene, one row per structure and walk.
#[derive(Clone, Debug, Serialize)]
pub struct RaySetReport {
    /// Which rays.
    pub kind: RayKind,
    /// `closest` or `any`.
    pub query: &'static str,
    /// Rays in the set.
    pub rays: usize,
    /// One row per structure and walk; the first is the reference of the hit comparisons.
    pub rows: Vec<TraceRow>,
    /// Every row of vkrt's own structures found as many hits as the first, and a walk
    /// measured both ways the same hits through texel buffers as through storage buffers.
    pub vkrt_hits_agree: bool,
}

/// One structure (and walk) tracing one ray set.
#[derive(Clone, Debug, Serialize)]
pub struct TraceRow {
    /// [`AccelChoice::label`], or the peer's name.
    pub structure: String,
    /// Who traced it.
    pub backend: Backend,
    /// The structure's build, milliseconds (shared by the walks of one structure).
    pub build_ms: f64,
    /// Best of the repetitions, milliseconds (GPU timestamps; a CPU peer's wall time).
    pub trace_ms: f64,
    /// Rays / trace time, millions per second (0 for no rays).
    pub mrays_per_s: f64,
    /// Rays that hit something (closest hit: found one; any hit: blocked).
    pub hits: usize,
    /// Whether this row traced the same primitives as the first (a peer without spheres
    /// does not, on a scene with spheres).
    pub hits_comparable: bool,
    /// `hits` minus the first row's, where comparable.
    pub hits_vs_first: Option<i64>,
    /// `mrays_per_s` over the `driver` row's (`None` without one).
    pub over_driver: Option<f64>,
    /// How a vkrt walk read the structure (`None` for the driver's and peers' rows).
    pub node_access: Option<NodeAccess>,
    /// For a walk measured both ways, on its texel row: whether every hit (t, primitive,
    /// u, v) equals the storage row's, bit for bit.
    pub same_hits_as_storage: Option<bool>,
    /// What sets the row apart (e.g. rays out of traversal steps, a peer's triangles only).
    pub note: Option<String>,
}

impl TraceRow {
    /// A row of `rays` rays traced in `trace_ms` with `hits` hits; [`RaySetReport::finish`]
    /// fills in the comparisons.
    pub fn new(
        structure: impl Into<String>,
        backend: Backend,
        build_ms: f64,
        trace_ms: f64,
        rays: usize,
        hits: usize,
    ) -> Self {
        Self {
            structure: structure.into(),
            backend,
            build_ms,
            trace_ms,
            mrays_per_s: mrays_per_s(rays, trace_ms),
            hits,
            hits_comparable: true,
            hits_vs_first: None,
            over_driver: None,
            node_access: None,
            same_hits_as_storage: None,
            note: None,
        }
    }
}

/// Millions of rays per second; 0 when nothing was timed (no rays).
fn mrays_per_s(rays: usize, ms: f64) -> f64 {
    if ms > 0.0 {
        rays as f64 / (ms * 1e3)
    } else {
        0.0
    }
}

impl RaySetReport {
    fn new(kind: RayKind, rays: usize) -> Self {
        Self {
            kind,
            query: match kind.query() {
                Query::Closest => "closest",
                Query::Any => "any",
            },
            rays,
            rows: Vec::new(),
            vkrt_hits_agree: true,
        }
    }

    /// Fills in each row's comparisons with the first row and the `driver` row (call again
    /// after adding rows).
    pub fn finish(&mut self) {
        let first = self.rows.first().map_or(0, |r| r.hits) as i64;
        let driver = self
            .rows
            .iter()
            .find(|r| r.structure == AccelChoice::driver(Prefer::FastTrace).label())
            .map(|r| r.mrays_per_s)
            .filter(|&m| m > 0.0);
        for r in &mut self.rows {
            r.hits_vs_first = r.hits_comparable.then_some(r.hits as i64 - first);
            r.over_driver = driver.map(|d| r.mrays_per_s / d);
        }
        self.vkrt_hits_agree = self
            .rows
            .iter()
            .filter(|r| r.backend == Backend::Vkrt)
            .all(|r| r.hits_vs_first == Some(0) && r.same_hits_as_storage != Some(false));
    }
}

/// Why the device has no `driver` rows, or `None` where it has them.
pub fn driver_note(ctx: &Context) -> Option<String> {
    (!ctx.info().features.ray_query).then(|| {
        format!(
            "driver: skipped — {} has no VK_KHR_ray_query (Mesa's lavapipe has it from 25.x)",
            ctx.info().device
        )
    })
}

/// Measures every scene (see the module docs).
pub fn run(ctx: &Context, scenes: &[BenchScene], opt: &BenchOptions) -> Result<TraceBenchReport> {
    let mut out = TraceBenchReport {
        device: ctx.info().device.clone(),
        node_access: opt.accesses_on(ctx),
        ray_query: ctx.info().features.ray_query,
        driver_note: driver_note(ctx),
        size: opt.size,
        reps: opt.reps.max(1),
        scenes: Vec::new(),
    };
    for scene in scenes {
        log::info!("bench trace: {}", scene.name);
        out.scenes.push(bench_scene(ctx, scene, opt)?.0);
    }
    Ok(out)
}

/// The structures to build, each with the walks that trace it: every [`AccelChoice`] the
/// device has, and the driver's structure built for a fast build too. A BVH walked wide is a
/// structure of its own (its wide nodes are made after the build).
pub fn structures(ctx: &Context) -> Vec<(AccelChoice, Vec<AccelChoice>)> {
    let mut choices = AccelChoice::all_on(ctx);
    if ctx.info().features.ray_query {
        choices.push(AccelChoice::driver(Prefer::FastBuild));
    }
    let mut out: Vec<(AccelChoice, Vec<AccelChoice>)> = Vec::new();
    for c in choices {
        match out.last_mut() {
            Some((s, walks))
                if s.kind == c.kind
                    && s.prefer == c.prefer
                    && (s.walk == Traversal::Wide) == (c.walk == Traversal::Wide) =>
            {
                walks.push(c)
            }
            _ => out.push((c, vec![c])),
        }
    }
    out
}

/// Measures one scene; also returns the ray sets it traced (primary, shadow, mirror), so a
/// caller can hand the same rays to another peer and add its rows.
pub fn bench_scene(
    ctx: &Context,
    scene: &BenchScene,
    opt: &BenchOptions,
) -> Result<(SceneReport, Vec<RaySet>)> {
    let reps = opt.reps.max(1);
    let g = &scene.geometry;
    let (width, height) = scene.image(opt.size);
    let mut sets = vec![RaySet {
        kind: RayKind::Primary,
        rays: scene.primary_rays(opt.size),
    }];
    let mut reports: Vec<RaySetReport> = Vec::new();
    let mut builds = Vec::new();
    let accesses = opt.accesses_on(ctx);
    // One structure on the device at a time: the 500 K scenes' nine are large together.
    for (structure, walks) in structures(ctx) {
        let (geom, build_ms) = best_build(ctx, structure, g, reps)?;
        let backend = match structure.kind {
            AccelKind::Driver => Backend::Driver,
            _ => Backend::Vkrt,
        };
        let name = match structure.kind {
            AccelKind::Driver => structure.label(),
            _ if structure.walk == Traversal::Wide => structure.label(),
            kind => kind.name().to_string(),
        };
        builds.push(BuildRow {
            structure: name,
            backend,
            ms: build_ms,
        });
        // The driver's walk reads its own structure: one row, whatever the accesses.
        let walk_accesses = match backend {
            Backend::Vkrt => accesses.clone(),
            _ => vec![NodeAccess::for_device(ctx)],
        };
        for walk in walks {
            // By index: the first primary trace adds the secondary sets to `sets`.
            for k in 0..RayKind::ALL.len() {
                let mut storage_hits: Option<Vec<Hit>> = None;
                for &access in &walk_accesses {
                    let set = &sets[k];
                    let (hits, ms, exhausted) = best_trace(ctx, walk, access, &geom, set, reps)?;
                    let n_hits = hits.iter().filter(|h| h.is_hit()).count();
                    let label = match walk_accesses.len() {
                        1 => walk.label(),
                        _ => format!("{} ({})", walk.label(), access.name()),
                    };
                    let mut row =
                        TraceRow::new(label, backend, build_ms, ms, set.rays.len(), n_hits);
                    if backend == Backend::Vkrt {
                        row.node_access = Some(access);
                    }
                    // The texel row against the storage row before it, ray by ray.
                    if let (Some(before), NodeAccess::Texel) = (&storage_hits, access) {
                        row.same_hits_as_storage = Some(same_hits(before, &hits));
                    }
                    row.note = row_note(exhausted, row.same_hits_as_storage);
                    if reports.len() == k {
                        reports.push(RaySetReport::new(set.kind, set.rays.len()));
                    }
                    reports[k].rows.push(row);
                    if set.kind == RayKind::Primary && sets.len() == 1 {
                        let (shadow, mirror) = scene.secondary_rays(&set.rays, &hits);
                        sets.extend([shadow, mirror]);
                    }
                    if walk_accesses.len() > 1 && access == NodeAccess::Storage {
                        storage_hits = Some(hits);
                    }
                }
            }
        }
    }
    let mut ob_builds = obvhs_rows(g, &sets, &mut reports, reps);
    builds.append(&mut ob_builds);
    reports.iter_mut().for_each(RaySetReport::finish);
    let report = SceneReport {
        name: scene.name.clone(),
        triangles: g.triangle_count(),
        spheres: g.spheres.len(),
        width,
        height,
        light: scene.light.clone(),
        builds,
        ray_sets: reports,
    };
    Ok((report, sets))
}

/// obvhs's build row and its row in each ray set (see [`ObvhsPeer`]).
fn obvhs_rows(
    g: &TraceGeometry,
    sets: &[RaySet],
    reports: &mut [RaySetReport],
    reps: u32,
) -> Vec<BuildRow> {
    let Some(peer) = (0..reps)
        .filter_map(|_| ObvhsPeer::build(g))
        .min_by(|a, b| a.build_ms.total_cmp(&b.build_ms))
    else {
        return Vec::new();
    };
    let spheres = !g.spheres.is_empty();
    for (set, report) in sets.iter().zip(reports) {
        let (mut hits, mut ms) = (0, f64::MAX);
        for _ in 0..reps {
            let (h, t) = peer.trace(&set.rays, set.kind.query());
            (hits, ms) = (h, ms.min(t));
        }
        let mut row = TraceRow::new(
            "obvhs",
            Backend::CpuPeer,
            peer.build_ms,
            ms,
            set.rays.len(),
            hits,
        );
        if spheres {
            // Never compare hits of other geometry as if they were a difference.
            row.hits_comparable = false;
            row.note = Some("triangles only".into());
        }
        report.rows.push(row);
    }
    vec![BuildRow {
        structure: "obvhs".into(),
        backend: Backend::CpuPeer,
        ms: peer.build_ms,
    }]
}

/// `choice`'s structure over `g`, built `reps` times (the last one is kept), and the best
/// build time.
pub fn best_build(
    ctx: &Context,
    choice: AccelChoice,
    g: &TraceGeometry,
    reps: u32,
) -> Result<(GpuGeometry, f64)> {
    let builder = AccelBuilder::for_choice(ctx, choice)?;
    let mut best = f64::MAX;
    let mut kept = None;
    for _ in 0..reps {
        drop(kept.take()); // the previous structure's memory first
        let (geom, ms) = build(ctx, &builder, g)?;
        best = best.min(ms);
        kept = Some(geom);
    }
    Ok((kept.expect("at least one build"), best))
}

/// [`GpuGeometry::build_fitting`]: the build and its milliseconds.
pub(crate) fn build(
    ctx: &Context,
    builder: &AccelBuilder,
    g: &TraceGeometry,
) -> Result<(GpuGeometry, f64)> {
    GpuGeometry::build_fitting(ctx, builder, g)
}

/// What sets a vkrt row apart: rays out of steps, hits unlike the storage walk's.
fn row_note(exhausted: u32, same_hits_as_storage: Option<bool>) -> Option<String> {
    let mut notes = Vec::new();
    if exhausted > 0 {
        notes.push(format!("{exhausted} rays ran out of traversal steps"));
    }
    if same_hits_as_storage == Some(false) {
        notes.push("hits differ from the storage walk's".to_string());
    }
    (!notes.is_empty()).then(|| notes.join("; "))
}

/// Whether two walks answered every ray alike, bit for bit (t, primitive, u, v).
fn same_hits(a: &[Hit], b: &[Hit]) -> bool {
    a.len() == b.len() && bytemuck::cast_slice::<Hit, u32>(a) == bytemuck::cast_slice::<Hit, u32>(b)
}

/// `set` traced `reps` times through `geom`, walked as `walk` reading the nodes as `access`
/// says: the hits, the best kernel milliseconds and how many rays ran out of steps.
pub fn best_trace(
    ctx: &Context,
    walk: AccelChoice,
    access: NodeAccess,
    geom: &GpuGeometry,
    set: &RaySet,
    reps: u32,
) -> Result<(Vec<Hit>, f64, u32)> {
    let opt = TraceOptions {
        query: set.kind.query(),
        ..TraceOptions::default()
    };
    let tracer = Tracer::for_accel_reading(ctx, &opt, walk.traversal(), access)?;
    let mut best = (Vec::new(), f64::MAX, 0);
    for _ in 0..reps {
        let b = tracer.trace_batched(ctx, geom, &set.rays, 0.0, None)?;
        // No rays, no kernel: 0 ms.
        let ms = b.profile.ms("trace").unwrap_or(0.0);
        if ms <= best.1 {
            best = (b.hits, ms, b.exhausted);
        }
    }
    Ok(best)
}
