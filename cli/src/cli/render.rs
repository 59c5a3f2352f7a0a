//! `vkrt render`: a scene rendered to an image (.png, .jpg, .exr or .pfm) by the wavefront
//! renderer, the structure built on the device in the first sample's submission.

use std::path::PathBuf;

use clap::Args;

use super::common::{
    check_resolution, context, extend_json, load_scene, memory_json, CliResult, IntersectorArg,
    StructureArgs,
};

#[derive(Args)]
pub struct RenderArgs {
    /// Scene (.toml, .obj, .scn text); omit for the embedded default scene.
    scene: Option<PathBuf>,
    /// Output image, by extension: .png or .jpg/.jpeg (8-bit sRGB), .exr or .pfm (linear
    /// float radiance).
    #[arg(short, long, default_value = "render.png")]
    output: PathBuf,
    /// Samples per pixel (default: the scene's; 1 if no effect of the scene needs more).
    #[arg(long)]
    spp: Option<u32>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Render frame K of an animated scene (its time K / fps), as `vkrt animate` does.
    #[arg(long)]
    frame: Option<u32>,
    /// Print the render plan (passes, shader variants) and stop.
    #[arg(long)]
    plan: bool,
    /// Force every pass and shader branch on (the image must not change).
    #[arg(long)]
    all_effects: bool,
    /// Ray/triangle test: watertight (default) or moller-trumbore.
    #[arg(long, value_enum, default_value_t = IntersectorArg::Watertight)]
    intersector: IntersectorArg,
    #[command(flatten)]
    structure: StructureArgs,
    #[arg(long)]
    json: bool,
}

pub fn run(args: RenderArgs, validate: bool) -> CliResult<()> {
    let RenderArgs {
        scene,
        output,
        spp,
        width,
        height,
        frame,
        plan,
        all_effects,
        intersector,
        structure,
        json,
    } = args;
    let mut opt = vkrt::render::RenderOptions {
        width,
        height,
        spp,
        all_effects,
        accel: structure.choice(None),
        flatten: structure.flatten,
        // (from the device, when it renders)
        max_level_primitives: None,
    };
    // An unsupported image extension fails here, before the scene or the device is touched.
    vkrt::render::output::ImageFormat::from_path(&output)?;
    check_resolution(&opt)?;
    let mut scene = load_scene(&scene)?;
    if let Some(k) = frame {
        let frames = scene.animation.map_or(0, |a| a.frames);
        if k >= frames {
            return Err(match frames {
                0 => "--frame: the scene has no [animation]".to_string(),
                n => format!("--frame {k}: the scene has frames 0..{n}"),
            }
            .into());
        }
        scene = scene.at_frame(k);
    }
    if plan {
        let plan = vkrt::render::Plan::new(&scene, &opt)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&plan)?);
        } else {
            print!("{plan}");
        }
        return Ok(());
    }
    // Fail before rendering if the image cannot be written there.
    let dir = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        return Err(format!("{}: no such directory for the output image", dir.display()).into());
    }
    let triangles = scene.triangle_count();
    let ctx = context(validate)?;
    opt.accel = structure.choice(Some(&ctx));
    let trace = vkrt::trace::TraceOptions {
        intersector: intersector.into(),
        ..Default::default()
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} samples {pos}/{len} [{bar:30}] {elapsed_precise} (eta {eta})",
        )
        .map_err(|e| e.to_string())?,
    );
    let rendered = vkrt::render::render_scene_owned(&ctx, scene, &opt, &trace, |done, spp| {
        if spp > 1 {
            bar.set_length(spp as u64);
            bar.set_position(done as u64);
        }
    });
    bar.finish_and_clear();
    let r = rendered.map_err(|e| e.to_string())?;
    let p = &r.plan;
    vkrt::render::output::write_image(
        &output,
        p.width,
        p.height,
        &r.image.rgba,
        &r.image.radiance,
    )?;
    if r.image.counts.exhausted > 0 {
        log::warn!(
            "{} rays ran out of traversal steps (counted as misses)",
            r.image.counts.exhausted
        );
    }
    if json {
        let mut v = serde_json::json!({
            "width": p.width,
            "height": p.height,
            "spp": p.spp,
            "accel": p.accel.label(),
            "levels": p.levels,
            "pieces_of": p.pieces_of,
            "build_ms": r.build_ms,
            "render_ms": r.render_ms,
            "build_attempts": r.image.build_attempts,
            "submits": r.image.traffic.submits,
            "readback_bytes": r.image.readback_before_trace,
            "readback_bytes_total": r.image.traffic.readback_bytes,
            "passes": r.passes,
            "copy_gib_per_s": ctx.copy_baseline(),
            "warm_up_ms": r.warm_up_ms,
            "effects": p.effects,
            "mrays_per_s": r.mrays_per_s(),
            "rays": r.image.counts,
            "output": output.display().to_string(),
        });
        extend_json(&mut v, memory_json(triangles, &ctx.memory()));
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{}: {}x{}, {} spp, effects: {}",
            output.display(),
            p.width,
            p.height,
            p.spp,
            if p.effects.is_empty() {
                "none".into()
            } else {
                p.effects.join(", ")
            }
        );
        println!(
            "{} build {:.1} ms, render {:.1} ms, {:.2} Mrays/s",
            p.accel.label(),
            r.build_ms,
            r.render_ms,
            r.mrays_per_s()
        );
        // Invocations, bytes and bandwidth where --profile-stats counted them.
        let counted = r.passes.iter().any(|p| p.invocations.is_some());
        let copy = ctx.copy_baseline();
        let head = format!(
            "  {:<11} {:>12}      {:>10} {:>6} {:>10} {:>19}",
            "pass", "rays", "total", "runs", "median", "min-max"
        );
        match counted {
            true => println!(
                "{head}    {:>14} {:>10} {:>8} {:>7}",
                "invocations", "MiB", "GiB/s", "÷copy"
            ),
            false => println!("{head}"),
        }
        for pass in &r.passes {
            let s = pass.per_sample;
            let line = format!(
                "  {:<11} {:>12} rays {:>7.1} ms {:>6} {:>7.2} ms {:>8.2}-{:<7.2} ms",
                pass.name, pass.rays, pass.ms, s.count, s.median, s.min, s.max
            );
            if !counted {
                println!("{line}");
                continue;
            }
            let n = pass.invocations.map_or("-".into(), |n| n.to_string());
            let (mib, gib, of_copy) = match pass.bytes.filter(|_| pass.ms > 0.0) {
                Some(b) => {
                    let gib = b.gib_per_s(pass.ms);
                    (
                        format!("{:.1}", b.total() as f64 / f64::from(1u32 << 20)),
                        format!("{gib:.2}"),
                        copy.map_or("-".into(), |c| format!("{:.2}", gib / c)),
                    )
                }
                None => ("-".into(), "-".into(), "-".into()),
            };
            println!("{line} {n:>14} {mib:>10} {gib:>8} {of_copy:>7}");
        }
        println!(
            "  {:<11} {:>12}      {:>7.1} ms (kernels dispatched empty before sample 0)",
            "warm-up", "", r.warm_up_ms
        );
    }
    Ok(())
}
