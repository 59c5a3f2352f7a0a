//! `vkrt build`: builds one acceleration structure over a scene (the SAH BVH on the CPU's
//! threads, the kd-tree, LBVH or PLOC on the GPU, or the driver's own) and reports its
//! time and quality; `--reference` also builds the twin it must equal.

use std::path::PathBuf;

use clap::Args;

use super::common::{context, extend_json, load_scene, AccelArg, CliResult, Repeated};

#[derive(Args)]
pub struct BuildArgs {
    /// Scene (.toml, .obj, .scn text); omit for the embedded default scene.
    scene: Option<PathBuf>,
    /// The structure to build: sah-bvh (the SAH BVH, on the CPU's threads; the
    /// default, by measurement: docs/performance.md) or kdtree (the SAH kd-tree after Wu, Zhao & Liu 2011, on
    /// the GPU) or lbvh (LBVH, Karras 2012, on the GPU) or ploc (PLOC, on the GPU) or
    /// driver / driver-fast-build (the driver's own, where it has ray query).
    #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
    accel: AccelArg,
    /// kd-tree: also build the CPU twin (must be equal) and the full-clipping CPU
    /// reference; BVH: also build on one thread (must be equal).
    #[arg(long)]
    reference: bool,
    /// Kolodzey's (2014) termination: no SAH leaf test, leaves below 64 primitives.
    #[arg(long)]
    kolodzey_termination: bool,
    /// Warm builds timed after the first (which compiles the driver's pipelines and is
    /// reported apart): the times printed are their median.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    reps: u32,
    #[arg(long)]
    json: bool,
}

pub fn run(args: BuildArgs, validate: bool) -> CliResult<()> {
    let BuildArgs {
        scene,
        accel,
        reference,
        kolodzey_termination,
        reps,
        json,
    } = args;
    if accel == AccelArg::SahBvh {
        if kolodzey_termination {
            return Err(
                "--kolodzey-termination is the GPU kd-tree thesis's termination rule: add \
                        --accel kdtree"
                    .into(),
            );
        }
        return bvh_build_command(&load_scene(&scene)?, reference, reps, json);
    }
    let driver = match accel {
        AccelArg::Driver => Some(vkrt::accel::driver::Prefer::FastTrace),
        AccelArg::DriverFastBuild => Some(vkrt::accel::driver::Prefer::FastBuild),
        _ => None,
    };
    if let Some(prefer) = driver {
        if kolodzey_termination || reference {
            return Err(
                "--kolodzey-termination and --reference do not apply to the \
                        driver's structure (it is opaque)"
                    .into(),
            );
        }
        let ctx = context(validate)?;
        let scene = load_scene(&scene)?;
        return driver_build_command(&ctx, prefer, &scene, reps, json);
    }
    let gpu_bvh = match accel {
        AccelArg::Lbvh => Some(vkrt::accel::device::AccelKind::Lbvh),
        AccelArg::Ploc => Some(vkrt::accel::device::AccelKind::Ploc),
        _ => None,
    };
    if let Some(kind) = gpu_bvh {
        if kolodzey_termination {
            return Err(
                "--kolodzey-termination is the GPU kd-tree thesis's termination rule: add \
                        --accel kdtree"
                    .into(),
            );
        }
        let ctx = context(validate)?;
        let scene = load_scene(&scene)?;
        return gpu_bvh_build_command(&ctx, kind, &scene, (reference, reps), json);
    }
    // What is left is the kd-tree: clap refuses any other name.
    kdtree_build_command(
        validate,
        &scene,
        (reference, kolodzey_termination),
        reps,
        json,
    )
}

/// `vkrt build --accel kdtree`: the SAH kd-tree built on the GPU over the scene's triangles
/// at time 0; with `reference`, also its CPU twin (must be equal) and the full-clipping
/// CPU build.
fn kdtree_build_command(
    validate: bool,
    scene: &Option<PathBuf>,
    (reference, kolodzey_termination): (bool, bool),
    reps: u32,
    json: bool,
) -> CliResult<()> {
    let scene = load_scene(scene)?;
    flat_on_host(&scene)?;
    let triangles = scene.triangles_world(0.0);
    if triangles.is_empty() {
        return Err("the scene has no triangles to build a kd-tree over (spheres are not in the kd-tree yet)".into());
    }
    let mut params = vkrt::accel::kdtree::SahParams::default();
    if kolodzey_termination {
        params.sah_leaf_test = false;
        params.max_leaf_prims = 63;
    }
    let ctx = context(validate)?;
    let before = device_bytes_start(&ctx);
    let (report, _) = vkrt::accel::kdtree::report::build_report_repeated(
        &ctx, &triangles, &params, reference, reps,
    )?;
    if json {
        let mut v = serde_json::to_value(&report)?;
        extend_json(&mut v, device_bytes_json(&ctx, before, triangles.len()));
        let kd = vkrt::accel::device::AccelKind::KdTree;
        extend_json(&mut v, levels_json(&ctx, kd, &scene)?);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let spread = match report.reps {
            1 => format!(
                "{:.2} ms (warm; the first {:.2})",
                report.build_ms, report.first_build_ms
            ),
            n => format!(
                "{:.2} ms (median of {n} warm builds, {:.2}–{:.2}; the first {:.2})",
                report.build_ms, report.build_ms_min, report.build_ms_max, report.first_build_ms
            ),
        };
        println!(
            "{} triangles: GPU build {spread} in {} levels",
            report.primitives, report.levels
        );
        for (phase, ms) in &report.phases {
            println!("  {phase:<16} {ms:>9.2} ms");
        }
        println!(
            "{} nodes, {} leaves, depth {}, {} references ({:.2} per primitive), SAH cost {:.3}, {} bytes",
            report.nodes,
            report.leaves,
            report.max_depth,
            report.references,
            report.references as f64 / f64::from(report.primitives.max(1)),
            report.sah_cost,
            report.bytes
        );
        if let (Some(eq), Some(twin), Some(cost), Some(full)) = (
            report.equal_to_cpu_twin,
            report.cpu_twin_ms,
            report.full_clip_sah_cost,
            report.full_clip_ms,
        ) {
            println!("CPU twin {twin:.1} ms, equal to the GPU tree: {eq}");
            println!("full-clipping CPU build {full:.1} ms, SAH cost {cost:.3}");
            if !eq {
                return Err("the GPU tree differs from its CPU twin".into());
            }
        }
    }
    Ok(())
}

/// `vkrt build --accel sah-bvh`: the parallel node-queue build on every core over the scene's
/// primitives at the shutter-open time; with `reference`, also on one thread (must be equal).
fn bvh_build_command(
    scene: &vkrt::scene::Scene,
    reference: bool,
    reps: u32,
    json: bool,
) -> CliResult<()> {
    use vkrt::accel::bvh::{self, validate, BvhParams, Threading};
    flat_on_host(scene)?;
    let g = vkrt::accel::primitives::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let params = BvhParams::default();
    let all_cores = Threading::all_cores();
    let Threading::Queue { threads } = all_cores else {
        unreachable!("all_cores is the node queue")
    };
    let timed = |threading| bvh::build_timed(&g.boxes, &params, threading);
    let mut times = Repeated::default();
    let mut built = None;
    for i in 0..=reps as usize {
        // The previous tree goes before the next is built (the peak is one build).
        drop(built.take());
        let (tree, ms) = timed(all_cores)?;
        times.push(i, ms);
        built = Some(tree);
    }
    let tree = built.expect("built");
    validate::validate(&tree, &g.boxes).map_err(|e| format!("invalid BVH: {e}"))?;
    let single = if reference {
        Some(timed(Threading::Single)?)
    } else {
        None
    };
    let equal = single.as_ref().map(|(t, _)| *t == tree);
    let (shape, shape_line) = bvh_shape(&tree, &params);
    let mut report = serde_json::json!({
        "kind": "sah_bvh",
        "primitives": g.primitive_count(),
        "reps": reps,
        "threads": threads,
        "scheme": "queue",
        "params": params,
        "equal_to_single_thread": equal,
        "single_thread_ms": single.as_ref().map(|(_, ms)| *ms),
    });
    report.as_object_mut().expect("an object").extend(shape);
    extend_json(&mut report, times.json("build_ms"));
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} primitives: CPU build {} on {threads} threads (node queue)",
            g.primitive_count(),
            times.text()
        );
        println!("{shape_line}");
        if let (Some((_, ms)), Some(eq)) = (&single, equal) {
            println!("one thread {ms:.1} ms, the same tree: {eq}");
        }
    }
    if equal == Some(false) {
        return Err("the multithreaded BVH differs from the single-threaded one".into());
    }
    Ok(())
}

/// `vkrt build --accel lbvh|ploc`: LBVH, Karras 2012 or PLOC built on the device over the
/// scene's primitives at the shutter-open time, read back (this command is a tool),
/// validated; with `reference`, also the CPU twin (must be equal bit for bit).
fn gpu_bvh_build_command(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
    (reference, reps): (bool, u32),
    json: bool,
) -> CliResult<()> {
    use vkrt::accel::bvh::{validate, BvhParams};
    use vkrt::accel::device::AccelBuilder;
    use vkrt::accel::host::HostStructure;
    if let Err(flat) = vkrt::accel::primitives::TraceGeometry::check_flat_fits(ctx, scene) {
        return levels_only(ctx, kind, scene, flat, json);
    }
    let g = vkrt::accel::primitives::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let builder = AccelBuilder::new(ctx, kind)?;
    let before = device_bytes_start(ctx);
    // Once to compile and warm the pipelines, then the timed builds.
    let mut timed = None;
    let mut times = Repeated::default();
    let mut pass_times: Vec<(&str, Vec<f64>)> = vkrt::accel::bvh::GPU_BUILD_PASSES
        .iter()
        .map(|p| (*p, Vec::new()))
        .collect();
    for i in 0..=reps as usize {
        // The previous build's buffers go before the next is made (the peak is one build).
        drop(timed.take());
        let mut rec = vkrt::gpu::Recorder::new(ctx)?;
        let dev =
            match vkrt::accel::gpu_geometry::GpuGeometry::record_build(&mut rec, &builder, &g, 0) {
                Ok((dev, _)) => dev,
                // A scene too big to build flat may still build as two levels: say both.
                Err(flat) => return levels_only(ctx, kind, scene, flat, json),
            };
        let prof = rec.submit_and_wait()?;
        times.push(i, prof.ms("build").unwrap_or(0.0));
        for (name, ms) in pass_times.iter_mut().filter(|_| i > 0) {
            ms.extend(prof.ms(name));
        }
        timed = Some(dev);
    }
    let dev = timed.expect("built");
    let HostStructure::Bvh(tree) = dev.structure().download()? else {
        unreachable!("a GPU BVH")
    };
    validate::validate(&tree, &g.boxes).map_err(|e| format!("invalid {}: {e}", kind.name()))?;
    // Each pass's median over the warm builds.
    let passes: serde_json::Map<String, serde_json::Value> = pass_times
        .iter()
        .filter(|(_, ms)| !ms.is_empty())
        .map(|(name, ms)| (name.to_string(), vkrt::gpu::Spread::of(ms).median.into()))
        .collect();
    let bits = builder.lbvh_bits();
    let ploc_params = builder.ploc_params();
    let twin = match reference {
        true => {
            let t = std::time::Instant::now();
            let HostStructure::Bvh(twin) = builder.host_twin(&g)? else {
                unreachable!("a GPU BVH's twin is a BVH")
            };
            Some((twin, t.elapsed().as_secs_f64() * 1e3))
        }
        false => None,
    };
    let equal = twin.as_ref().map(|(t, _)| *t == tree);
    let params = BvhParams::default();
    let (shape, shape_line) = bvh_shape(&tree, &params);
    let mut report = serde_json::json!({
        "kind": kind.name(),
        "morton_bits": bits.spec(),
        "ploc_radius": ploc_params.map(|p| p.radius),
        "primitives": g.primitive_count(),
        "reps": reps,
        "passes_ms": passes,
        "equal_to_cpu_twin": equal,
        "cpu_twin_ms": twin.as_ref().map(|(_, ms)| *ms),
    });
    report.as_object_mut().expect("an object").extend(shape);
    extend_json(&mut report, times.json("build_ms"));
    extend_json(
        &mut report,
        device_bytes_json(ctx, before, g.primitive_count()),
    );
    if json {
        extend_json(&mut report, levels_json(ctx, kind, scene)?);
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} primitives: {} GPU build {} ({}-bit Morton codes)",
            g.primitive_count(),
            kind.name(),
            times.text(),
            bits.spec()
        );
        for (name, ms) in &passes {
            println!("  {name:<12} {:.3} ms", ms.as_f64().unwrap_or(0.0));
        }
        println!("{shape_line}");
        if let (Some((_, ms)), Some(eq)) = (&twin, equal) {
            println!("CPU twin {ms:.1} ms, the same tree: {eq}");
        }
    }
    if equal == Some(false) {
        return Err(format!("the GPU {} differs from its CPU twin", kind.name()).into());
    }
    Ok(())
}

/// `vkrt build --accel driver`: the driver's structure built over the scene's primitives at
/// the shutter-open time, twice (the first warms up), with the build's GPU time from
/// timestamps and the submission's wall time; its bytes as the driver reports them.
fn driver_build_command(
    ctx: &vkrt::gpu::Context,
    prefer: vkrt::accel::driver::Prefer,
    scene: &vkrt::scene::Scene,
    reps: u32,
    json: bool,
) -> CliResult<()> {
    use vkrt::accel::device::{AccelBuilder, AccelChoice, DevicePrimitives};
    use vkrt::accel::driver::{DriverAccel, DriverInput};
    vkrt::accel::primitives::TraceGeometry::check_flat_fits(ctx, scene)?;
    let g = vkrt::accel::primitives::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let builder = AccelBuilder::for_choice(ctx, AccelChoice::driver(prefer))?;
    let before = device_bytes_start(ctx);
    let prims = DevicePrimitives::upload(ctx, &g)?;
    let sizes = DriverAccel::sizes(ctx, &DriverInput::counts(&prims), prefer, false)?;
    let mut timed = None;
    let (mut times, mut walls) = (Repeated::default(), Repeated::default());
    for i in 0..=reps as usize {
        // The previous build's buffers go before the next is made (the peak is one build).
        drop(timed.take());
        let (mut accel, scratch) = builder.create(ctx, prims.count(), 0)?;
        let mut rec = vkrt::gpu::Recorder::new(ctx)?;
        rec.scope("build", |rec| {
            builder.record_build(rec, &mut accel, &prims, &g, &scratch)
        })?;
        let t = std::time::Instant::now();
        let prof = rec.submit_and_wait()?;
        walls.push(i, t.elapsed().as_secs_f64() * 1e3);
        times.push(i, prof.ms("build").unwrap_or(0.0));
        timed = Some((accel, scratch));
    }
    drop(timed);
    if json {
        let mut v = serde_json::json!({
            "kind": "driver",
            "prefer": prefer,
            "primitives": g.primitive_count(),
            "reps": reps,
            "submit_wall_ms": walls.spread().median,
            "bytes": sizes.structure_bytes,
            "build_scratch_bytes": sizes.build_scratch_bytes,
        });
        extend_json(&mut v, times.json("build_ms"));
        extend_json(&mut v, device_bytes_json(ctx, before, g.primitive_count()));
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} primitives: driver build ({}) {} on the GPU, submission {:.2} ms wall \
             (median); {} bytes, {} bytes of scratch",
            g.primitive_count(),
            prefer.name(),
            times.text(),
            walls.spread().median,
            sizes.structure_bytes,
            sizes.build_scratch_bytes
        );
    }
    Ok(())
}

/// Starts measuring the device memory a build needs: vkrt's live bytes now.
fn device_bytes_start(ctx: &vkrt::gpu::Context) -> u64 {
    ctx.reset_memory_peak();
    ctx.memory().vkrt_bytes
}

/// `device_bytes`: the most device memory vkrt's buffers held at once since `before`
/// (primitives, structure, scratch, the build's read-backs), and per primitive.
fn device_bytes_json(ctx: &vkrt::gpu::Context, before: u64, n: usize) -> serde_json::Value {
    let bytes = ctx.memory().vkrt_peak_bytes.saturating_sub(before);
    serde_json::json!({
        "device_bytes": bytes,
        "device_bytes_per_primitive": bytes as f64 / n.max(1) as f64,
    })
}

/// `levels`: where the scene names a mesh more than once, the bytes of its two levels as
/// `vkrt trace` builds them (bottom levels of `kind`, the top level); absent otherwise.
fn levels_json(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
) -> CliResult<serde_json::Value> {
    use vkrt::accel::two_levels::TwoLevelScene;
    use vkrt::trace::instanced::level_bytes;
    let Some(two) = TwoLevelScene::of(scene, scene.camera.shutter_open) else {
        return Ok(serde_json::json!({}));
    };
    let choice = vkrt::accel::device::AccelChoice::new(kind, Default::default());
    Ok(serde_json::json!({ "levels": level_bytes(ctx, choice, &two)? }))
}

/// `vkrt build` of a scene whose flat build failed with `flat`: where meshes repeat, the
/// bytes of its two levels and why it does not build flat; else the error.
fn levels_only(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
    flat: vkrt::gpu::GpuError,
    json: bool,
) -> CliResult<()> {
    use vkrt::accel::two_levels::TwoLevelScene;
    use vkrt::trace::instanced::level_bytes;
    let Some(two) = TwoLevelScene::of(scene, scene.camera.shutter_open) else {
        return Err(flat.into());
    };
    let choice = vkrt::accel::device::AccelChoice::new(kind, Default::default());
    let levels = level_bytes(ctx, choice, &two)?;
    if json {
        let v = serde_json::json!({
            "kind": kind.name(),
            "primitives": scene.triangle_count() + scene.spheres.len(),
            "flat_error": flat.to_string(),
            "levels": levels,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("flat: {flat}");
        println!(
            "as two levels: {} bottom levels ({} unique primitives, {} bytes) under {} \
             instances ({} bytes)",
            levels.bottom_levels,
            levels.unique_primitives,
            levels.bottom_bytes,
            levels.instances,
            levels.top_bytes
        );
    }
    Ok(())
}

/// What `vkrt build --json` reports of a BVH's shape, and the same as a line of text.
fn bvh_shape(
    tree: &vkrt::accel::bvh::Bvh,
    params: &vkrt::accel::bvh::BvhParams,
) -> (serde_json::Map<String, serde_json::Value>, String) {
    let sah = vkrt::accel::bvh::validate::sah_cost(tree, params);
    let v = serde_json::json!({
        "nodes": tree.nodes.len(),
        "leaves": tree.leaf_count(),
        "max_depth": tree.depth(),
        "sah_cost": sah,
        "references": tree.refs.len(),
        "bytes": tree.bytes(),
    });
    let line = format!(
        "{} nodes, {} leaves, depth {}, SAH cost {sah:.3}, {} bytes",
        tree.nodes.len(),
        tree.leaf_count(),
        tree.depth(),
        tree.bytes()
    );
    let serde_json::Value::Object(map) = v else {
        unreachable!("an object")
    };
    (map, line)
}

/// Refuses a CPU build over more triangles than a scene may hold, which only a scene naming
/// meshes many times reaches when flattened (every copy held).
fn flat_on_host(scene: &vkrt::scene::Scene) -> CliResult<()> {
    use vkrt::scene::limits::MAX_TRIANGLES;
    let n = scene.triangle_count() as u64;
    if n > MAX_TRIANGLES {
        return Err(format!(
            "flattened, the scene holds {n} triangles (every copy of its repeated meshes), \
             above the {MAX_TRIANGLES} one structure is built over here; `vkrt trace` and \
             `vkrt render` trace it as two levels, each mesh held once"
        )
        .into());
    }
    Ok(())
}
