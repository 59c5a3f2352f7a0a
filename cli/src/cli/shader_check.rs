//! `vkrt shader-check`: a renderer's own `GL_EXT_ray_query` compute shader run over a scene
//! and a ray file through vkrt and through the driver's own ray query, compared ray by ray
//! (the work is `vkrt::shader_check`'s).

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use vkrt::shader_check::{self as check, Through};

use super::common::{context, load_scene, CliResult, TraversalArg};

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum ThroughArg {
    /// vkrt and the driver's ray query, compared (vkrt alone where the device has no ray
    /// query).
    Both,
    /// vkrt alone.
    Vkrt,
    /// The driver's ray query alone.
    Driver,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum ViaArg {
    /// Compile the GLSL with vkrt's include (`vkrt/ext_ray_query.glsl`).
    Include,
    /// Compile the GLSL for the driver's ray query, then rewrite its SPIR-V with vkrt's pass
    /// (`vkrt lower`): no include, as for a shader from any compiler.
    Pass,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum BottomArg {
    /// Kolodzey's SAH kd-tree (opaque triangles only).
    Kdtree,
    Lbvh,
    Ploc,
    SahBvh,
}

#[derive(Args)]
pub struct ShaderCheckArgs {
    /// The compute shader: GLSL (compiled with glslc or the program VKRT_GLSLC names); or,
    /// run through vkrt as the SPIR-V pass rewrites it, SPIR-V for the driver's ray query
    /// (`.spv`, from any compiler) or Slang and HLSL (`.slang`, `.hlsl`: entry point `main`,
    /// compiled by slangc or the program VKRT_SLANGC names).
    shader: PathBuf,
    /// Scene (.toml, .obj, .scn text).
    scene: PathBuf,
    /// The ray file (.rays: 32 bytes a ray, origin and tMin then direction and tMax, f32
    /// little-endian; or .csv).
    #[arg(long)]
    rays: PathBuf,
    /// Which ray queries run the shader.
    #[arg(long, value_enum, default_value_t = ThroughArg::Both)]
    through: ThroughArg,
    /// The width of the image the rays cover, in row order, for a shader with a
    /// two-dimensional workgroup (local_size_x by local_size_y pixels): it reads the width as
    /// its push block's second word.
    #[arg(long)]
    width: Option<u32>,
    /// How a GLSL shader reaches vkrt's walk (a `.spv` always goes through the pass).
    #[arg(long, value_enum, default_value_t = ViaArg::Include)]
    via: ViaArg,
    /// vkrt's bottom levels (the top level is an LBVH).
    #[arg(long, value_enum, default_value_t = BottomArg::Lbvh)]
    accel: BottomArg,
    /// How vkrt walks its bottom levels: the device's fastest (auto: `vkrt info` says which),
    /// binary nodes (stack or bitstack: the query's walk is the stack walk either way) or
    /// 4-wide ones. The answers are the same.
    #[arg(long, value_enum, default_value_t = TraversalArg::Auto)]
    traversal: TraversalArg,
    /// Write the results (16 bytes a ray, as the shader wrote them): the driver's, or vkrt's
    /// where the driver did not run. Written atomically; nothing is written on an error.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: ShaderCheckArgs, validate: bool) -> CliResult<()> {
    let through = match args.through {
        ThroughArg::Both => Through::Both,
        ThroughArg::Vkrt => Through::Vkrt,
        ThroughArg::Driver => Through::Driver,
    };
    let kind = match args.accel {
        BottomArg::Kdtree => vkrt::accel::device::AccelKind::KdTree,
        BottomArg::Lbvh => vkrt::accel::device::AccelKind::Lbvh,
        BottomArg::Ploc => vkrt::accel::device::AccelKind::Ploc,
        BottomArg::SahBvh => vkrt::accel::device::AccelKind::SahBvh,
    };
    // Everything that can be refused before any GPU work: the shader (compiled for each path
    // and its interface checked), the rays, the scene.
    let (mut shader, lowered_from) = compile(&args, through)?;
    for (_, iface) in shader.vkrt.iter_mut().chain(shader.native.iter_mut()) {
        let two_d = iface.local_size.is_some_and(|s| s[1] > 1);
        match (two_d, args.width) {
            (true, None) | (true, Some(0)) => {
                return Err(format!(
                    "{}: its workgroup is two-dimensional: give the image's width, --width W",
                    args.shader.display()
                )
                .into())
            }
            (false, Some(_)) => {
                return Err(format!(
                    "{}: --width is for a shader with a two-dimensional workgroup",
                    args.shader.display()
                )
                .into())
            }
            _ => iface.grid_width = args.width,
        }
    }
    if shader.inserted_include {
        log::info!(
            "{} does not include \"{}\": inserted after its #extension lines",
            args.shader.display(),
            check::compile::INCLUDE
        );
    }
    let rays = vkrt::trace::files::read_rays(&args.rays)?;
    if u32::try_from(rays.len()).is_err() {
        return Err(format!(
            "{}: {} rays: the ray count is a 32-bit push constant",
            args.rays.display(),
            rays.len()
        )
        .into());
    }
    let scene = load_scene(&Some(args.scene.clone()))?;
    let levels = check::scene_levels(&scene);
    drop(scene);
    if through != Through::Driver {
        levels
            .check_kind(kind)
            .map_err(|e| format!("--accel {}: {e}", kind.name()))?;
    }

    let ctx = context(validate)?;
    // A module the pass lowered is lowered again for a device with a loop budget, with the
    // walk for it (the include's takes the specialization constant).
    if let (Some(native), Some(_)) = (&lowered_from, ctx.info().loop_budget) {
        let options = vkrt::spirv::LowerOptions::for_device(ctx.info());
        let (words, mut iface) = check::lower_shader_with(&args.shader, native, &options)?;
        iface.grid_width = args.width;
        shader.vkrt = Some((words, iface));
    }
    let has_ray_query = ctx.info().features.ray_query;
    let native = match through {
        Through::Vkrt => false,
        Through::Driver => true,
        Through::Both if !has_ray_query => {
            log::warn!(
                "{} has no ray query (VK_KHR_ray_query): the shader ran through vkrt alone",
                ctx.info().device
            );
            false
        }
        Through::Both => true,
    };
    let vkrt_run = match &shader.vkrt {
        Some((words, iface)) => {
            let walk = super::common::traversal(args.traversal, Some(&ctx));
            let choice = vkrt::accel::device::AccelChoice::new(kind, walk);
            Some(check::run_vkrt(
                &ctx,
                &levels,
                choice,
                (words, iface),
                &rays,
            )?)
        }
        None => None,
    };
    // Where the driver ends an invocation's loops after a budget of iterations in all,
    // the walk's steps count against the shader's own loops: said, since what is cut
    // is cut silently.
    let loop_budget = ctx.info().loop_budget.filter(|_| vkrt_run.is_some());
    if let Some(budget) = loop_budget {
        log::warn!(
            "{} ends all of an invocation's loops once they have run {budget} iterations in \
             all (llvmpipe before Mesa 25): vkrt's walk for it spends about one per node \
             visit, pop and primitive test, so a shader that traces many rays per invocation \
             (hundreds of queries) can still have its own loops cut short, silently; a query \
             the budget cut reports vkrtRayQueryExhausted",
            ctx.info().device
        );
    }
    let driver_run = match (&shader.native, native) {
        (Some((words, iface)), true) => {
            Some(check::run_driver(&ctx, &levels, (words, iface), &rays)?)
        }
        _ => None,
    };
    let messages = ctx.take_validation_messages();
    if !messages.is_empty() {
        for m in &messages {
            log::error!("validation: {m:?}");
        }
        return Err(format!("{} validation messages", messages.len()).into());
    }
    let mismatches = match (&driver_run, &vkrt_run) {
        (Some(d), Some(v)) => check::mismatches(&d.results, &v.results),
        _ => Vec::new(),
    };
    if let Some(out) = &args.output {
        let written = driver_run
            .as_ref()
            .or(vkrt_run.as_ref())
            .expect("a path ran");
        vkrt::gpu::write_atomically(out, bytemuck::cast_slice(&written.results))?;
    }
    let ms = |r: &Option<check::PathRun>| r.as_ref().and_then(|r| r.ms);
    if args.json {
        let first: Vec<serde_json::Value> = mismatches
            .iter()
            .take(10)
            .map(|(ray, d, v)| serde_json::json!({ "ray": ray, "driver": d, "vkrt": v }))
            .collect();
        let v = serde_json::json!({
            "rays": rays.len(),
            "native": driver_run.is_some(),
            "mismatching_rays": mismatches.len(),
            "mismatches": first,
            "vkrt_ms": ms(&vkrt_run),
            "driver_ms": ms(&driver_run),
            "loop_budget": loop_budget,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let time = |name: &str, r: &Option<check::PathRun>| match r {
            Some(r) => format!(
                "{name} {}",
                r.ms.map_or_else(|| "ran".into(), |ms| format!("{ms:.3} ms on the GPU"))
            ),
            None => format!("{name} did not run"),
        };
        println!(
            "{} rays: {}, {}; {} rays differ",
            rays.len(),
            time("vkrt", &vkrt_run),
            time("the driver's ray query", &driver_run),
            mismatches.len()
        );
        for (ray, d, v) in mismatches.iter().take(10) {
            println!("ray {ray}: driver {d:?}, vkrt {v:?}");
        }
        if let Some(out) = &args.output {
            println!("wrote {}", out.display());
        }
    }
    if !mismatches.is_empty() {
        return Err(format!(
            "{} of {} rays differ between the driver's ray query and vkrt",
            mismatches.len(),
            rays.len()
        )
        .into());
    }
    Ok(())
}

/// The shader's variants for the paths `through` asks for: GLSL with the include, GLSL for
/// the driver lowered by the pass, or SPIR-V as given and lowered; with the driver's
/// SPIR-V where the pass lowered it, to be lowered again once the device is known.
fn compile(
    args: &ShaderCheckArgs,
    through: Through,
) -> CliResult<(check::CompiledShader, Option<Vec<u32>>)> {
    let path = &args.shader;
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let words = match ext.as_str() {
        "spv" => {
            let bytes = std::fs::read(path)
                .map_err(|e| format!("{}: cannot read the shader: {e}", path.display()))?;
            if bytes.len() % 4 != 0 {
                return Err(format!(
                    "{}: {} bytes: SPIR-V is a whole number of 32-bit words",
                    path.display(),
                    bytes.len()
                )
                .into());
            }
            Some(bytemuck::pod_collect_to_vec(&bytes))
        }
        "slang" | "hlsl" => Some(check::compile::compile_slang(path)?),
        _ => None,
    };
    if let Some(words) = words {
        let native = check::native_shader(path, words)?;
        let vkrt = (through != Through::Driver)
            .then(|| check::lower_shader(path, &native.0))
            .transpose()?;
        let lowered_from = vkrt.as_ref().map(|_| native.0.clone());
        let shader = check::CompiledShader {
            vkrt,
            native: (through != Through::Vkrt).then_some(native),
            inserted_include: false,
        };
        return Ok((shader, lowered_from));
    }
    let source = std::fs::read_to_string(path)
        .map_err(|e| format!("{}: cannot read the shader: {e}", path.display()))?;
    let include = check::compile::TempDir::new("shader-check-include")?;
    vkrt::accel::shader_library::write_to(include.path())?;
    if args.via == ViaArg::Include {
        let shader = check::compile_shader(path, &source, include.path(), through)?;
        return Ok((shader, None));
    }
    let mut shader = check::compile_shader(path, &source, include.path(), Through::Driver)?;
    let native = shader.native.take().expect("compiled for the driver");
    shader.vkrt = (through != Through::Driver)
        .then(|| check::lower_shader(path, &native.0))
        .transpose()?;
    let lowered_from = shader.vkrt.as_ref().map(|_| native.0.clone());
    shader.native = (through != Through::Vkrt).then_some(native);
    Ok((shader, lowered_from))
}
