//! `vkrt trace`: a batch of rays traced against a scene on the GPU (the structure built and
//! traced in one submission), the hits written atomically to `-o/--output`.

use std::path::PathBuf;

use clap::Args;

use super::common::{
    context, extend_json, load_scene, memory_json, CliResult, IntersectorArg, Repeated,
    StructureArgs,
};

#[derive(Args)]
pub struct TraceArgs {
    /// Scene (.toml, .obj, .scn text).
    scene: PathBuf,
    /// The ray file (.rays or .csv).
    #[arg(long)]
    rays: PathBuf,
    /// Where to write the hits (.csv for text, anything else binary); written atomically.
    // `--out` was the flag's name before every command's output file was `-o/--output`.
    #[arg(short, long, alias = "out")]
    output: Option<PathBuf>,
    /// Any-hit (shadow / visibility) queries instead of closest hit.
    #[arg(long)]
    any_hit: bool,
    /// The ray/triangle test.
    #[arg(long, value_enum, default_value_t = IntersectorArg::Watertight)]
    intersector: IntersectorArg,
    /// Rays per GPU batch (default and maximum: what fits the device's buffer limit).
    #[arg(long, hide = true)]
    batch_rays: Option<usize>,
    #[command(flatten)]
    structure: StructureArgs,
    /// Warm runs (build and trace) timed after the first, which compiles the driver's
    /// pipelines and is reported apart: the times printed are their median, and every run
    /// must give the first run's hits.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    reps: u32,
    #[arg(long)]
    json: bool,
}

pub fn run(args: TraceArgs, validate: bool) -> CliResult<()> {
    let TraceArgs {
        scene,
        rays,
        output,
        any_hit,
        intersector,
        batch_rays,
        structure,
        reps,
        json,
    } = args;
    let opt = vkrt::trace::TraceOptions {
        intersector: intersector.into(),
        query: if any_hit {
            vkrt::trace::Query::Any
        } else {
            vkrt::trace::Query::Closest
        },
        ..Default::default()
    };
    trace_command(
        validate,
        &scene,
        &rays,
        output.as_deref(),
        (&opt, structure),
        (batch_rays, reps),
        json,
    )
}

/// `vkrt trace`: everything is read and checked before the GPU work, the hits are written
/// atomically (no partial file on any error).
fn trace_command(
    validate: bool,
    scene_path: &std::path::Path,
    rays_path: &std::path::Path,
    out: Option<&std::path::Path>,
    (opt, structure): (&vkrt::trace::TraceOptions, StructureArgs),
    (batch_rays, reps): (Option<usize>, u32),
    json: bool,
) -> CliResult<()> {
    use vkrt::accel::primitives::TraceGeometry;
    use vkrt::trace::{files, gpu, instanced};
    let rays = files::read_rays(rays_path)?;
    let scene = load_scene(&Some(scene_path.to_path_buf()))?;
    let time = scene.camera.shutter_open;
    let triangles = scene.triangle_count();
    let ctx = context(validate)?;
    let (accel, flatten) = (structure.choice(Some(&ctx)), structure.flatten);
    // Meshes named more than once: bottom levels and instances, unless asked flat; a
    // scene past one buffer's range: its rest in pieces under identity instances.
    let per_level = vkrt::accel::two_levels::max_level_primitives(&ctx, accel.kind);
    if let Some(two) = (!flatten)
        .then(|| vkrt::accel::two_levels::TwoLevelScene::of_within(&scene, time, per_level))
        .flatten()
    {
        let extra = serde_json::json!({
            "levels": 2,
            "instances": two.mesh_instances(),
            "bottom_levels": two.bottoms.len(),
            "rest_pieces": two.rest_first.len(),
            "unique_primitives": two.unique_primitives,
        });
        let summary = format!(
            "{} primitives as {} bottom levels under {} instances ({} unique primitives)",
            scene.triangle_count() + scene.spheres.len(),
            two.bottoms.len(),
            two.instances.len(),
            two.unique_primitives
        );
        // The bottom levels hold what the walk reads: the scene and each level's host copy
        // go before the device copies grow.
        drop(scene);
        let mut runs = Runs::default();
        for i in 0..reps as usize {
            let done = instanced::build_and_trace(&ctx, accel, opt, &two, &rays, time)?;
            runs.record(
                i,
                done.bottom_build_ms + done.top_build_ms,
                done.trace_ms,
                &done.hits,
            )?;
        }
        // The last run takes the scene: each bottom level's host copy goes once it is built.
        let done = instanced::build_and_trace_owned(&ctx, accel, opt, two, &rays, time)?;
        let last = reps as usize;
        runs.record(
            last,
            done.bottom_build_ms + done.top_build_ms,
            done.trace_ms,
            &done.hits,
        )?;
        let mut extra = extra;
        extend_json(
            &mut extra,
            serde_json::json!({
                "bottom_build_ms": done.bottom_build_ms,
                "top_build_ms": done.top_build_ms,
                "bottom_bytes": done.bottom_bytes,
                "top_bytes": done.top_bytes,
            }),
        );
        let batch = gpu::TraceBatch {
            hits: done.hits,
            exhausted: done.exhausted,
            profile: Default::default(),
        };
        let report = TraceReport {
            accel,
            runs,
            attempts: 1,
            traffic: None,
            extra,
            summary,
            memory: (triangles, ctx.memory()),
        };
        return report_trace(&rays, &batch, out, report, json);
    }
    TraceGeometry::check_flat_fits(&ctx, &scene)?;
    let geometry = TraceGeometry::at_time(&scene, time);
    let builder = vkrt::accel::device::AccelBuilder::for_choice(&ctx, accel)?;
    let tracer = gpu::Tracer::for_accel(&ctx, opt, accel.traversal())?;
    // Upload, build and the first batch's trace in one submission; nothing read back
    // between build and trace.
    let mut runs = Runs::default();
    let mut last = None;
    for i in 0..=reps as usize {
        drop(last.take());
        let done =
            gpu::build_and_trace(&ctx, &builder, &tracer, &geometry, &rays, 0.0, batch_rays)?;
        let trace_ms = done.batch.profile.ms("trace").unwrap_or(0.0);
        runs.record(i, done.build_ms, trace_ms, &done.batch.hits)?;
        last = Some(done);
    }
    let done = last.expect("traced");
    let report = TraceReport {
        accel,
        runs,
        attempts: done.attempts,
        traffic: Some((
            done.traffic.submits,
            done.readback_before_trace,
            done.traffic.readback_bytes,
        )),
        extra: serde_json::json!({ "levels": 1 }),
        summary: format!("{} primitives", geometry.primitive_count()),
        memory: (triangles, ctx.memory()),
    };
    report_trace(&rays, &done.batch, out, report, json)
}

/// The build and trace times of repeated runs, and the first run's hits, which every later
/// run must give.
#[derive(Default)]
struct Runs {
    builds: Repeated,
    traces: Repeated,
    first_hits: Option<Vec<vkrt::trace::Hit>>,
}

impl Runs {
    /// Run `i`'s times and hits (run 0 is the first).
    fn record(
        &mut self,
        i: usize,
        build_ms: f64,
        trace_ms: f64,
        hits: &[vkrt::trace::Hit],
    ) -> CliResult<()> {
        self.builds.push(i, build_ms);
        self.traces.push(i, trace_ms);
        let Some(first) = &self.first_hits else {
            self.first_hits = Some(hits.to_vec());
            return Ok(());
        };
        // Bit for bit: a NaN field is the same NaN.
        let differ = first
            .iter()
            .zip(hits)
            .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
            .count();
        if differ > 0 || first.len() != hits.len() {
            return Err(format!(
                "run {} gave {differ} hits other than the first run's: the build or the walk \
                 is not deterministic",
                i + 1
            )
            .into());
        }
        Ok(())
    }
}

/// What `vkrt trace` prints besides the hits.
struct TraceReport {
    accel: vkrt::accel::device::AccelChoice,
    runs: Runs,
    attempts: u32,
    /// Submissions, bytes read back before the trace and in all (the flat path's).
    traffic: Option<(u64, u64, u64)>,
    extra: serde_json::Value,
    summary: String,
    /// The scene's triangles and the device's memory after the work (host memory is read
    /// where the report is made).
    memory: (usize, vkrt::gpu::MemoryUsage),
}

fn report_trace(
    rays: &[vkrt::trace::Ray],
    batch: &vkrt::trace::gpu::TraceBatch,
    out: Option<&std::path::Path>,
    r: TraceReport,
    json: bool,
) -> CliResult<()> {
    use vkrt::trace::files;
    // Invalid rays are answered as misses; say how many and why, never silently.
    let invalid = vkrt::trace::count_invalid(rays);
    let n_invalid: usize = invalid.iter().sum();
    if n_invalid > 0 {
        let why: Vec<String> = vkrt::trace::InvalidRay::ALL
            .iter()
            .zip(invalid)
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| format!("{n} {}", r.name()))
            .collect();
        log::warn!(
            "{n_invalid} of {} rays are invalid and reported as misses ({}); \
             a valid ray has a finite origin, direction and tmin, a non-zero direction and \
             tmin <= tmax (tmax = inf is unbounded)",
            rays.len(),
            why.join(", ")
        );
    }
    if batch.exhausted > 0 {
        log::warn!(
            "{} rays ran out of traversal steps and are reported as misses",
            batch.exhausted
        );
    }
    if let Some(out) = out {
        vkrt::gpu::write_atomically(out, &files::encode_hits(out, &batch.hits))?;
    }
    let hits = batch.hits.iter().filter(|h| h.is_hit()).count();
    let trace_ms = r.runs.traces.spread().median;
    let mrays_per_s = if trace_ms > 0.0 {
        rays.len() as f64 / (trace_ms * 1e3)
    } else {
        0.0
    };
    if json {
        let mut v = serde_json::json!({
            "rays": rays.len(),
            "hits": hits,
            "invalid": n_invalid,
            "invalid_by_reason": vkrt::trace::InvalidRay::ALL
                .iter()
                .zip(invalid)
                .map(|(r, n)| (r.name().to_string(), n.into()))
                .collect::<serde_json::Map<_, _>>(),
            "exhausted": batch.exhausted,
            "accel": r.accel.label(),
            "build_attempts": r.attempts,
            "reps": r.runs.traces.warm.len(),
            "mrays_per_s": mrays_per_s,
        });
        extend_json(&mut v, r.runs.builds.json("build_ms"));
        extend_json(&mut v, r.runs.traces.json("trace_ms"));
        if let Some((submits, before, total)) = r.traffic {
            extend_json(
                &mut v,
                serde_json::json!({
                    "submits": submits,
                    "readback_bytes": before,
                    "readback_bytes_total": total,
                }),
            );
        }
        extend_json(&mut v, r.extra);
        extend_json(&mut v, memory_json(r.memory.0, &r.memory.1));
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} rays, {} hits, {} misses: trace {:.3} ms on the GPU ({:.2} Mrays/s), {}",
            rays.len(),
            hits,
            rays.len() - hits,
            trace_ms,
            mrays_per_s,
            r.summary
        );
        println!(
            "build {}; trace {}",
            r.runs.builds.text(),
            r.runs.traces.text()
        );
        if let Some(out) = out {
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}
