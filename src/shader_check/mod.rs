//! `vkrt shader-check`: a renderer's own `GL_EXT_ray_query` compute shader run over a
//! scene's two levels and a ray file, through vkrt (the shader compiled with
//! `vkrt/ext_ray_query.glsl`) and through the driver's own ray query where the device has
//! it, and what it wrote compared ray by ray ([`compare`]).
//!
//! Everything that can be refused is refused before any GPU work: the shader is compiled
//! ([`compile`]) and its interface read from the SPIR-V ([`reflect`]) and checked
//! ([`check_interface`]), the scene and the rays are read. The interface:
//!
//! ```glsl
//! layout(local_size_x = 64) in;                                          // one invocation per ray
//! layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;   // any name
//! layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
//! layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
//! layout(push_constant) uniform Count { uint rayCount; };
//! // Optional: the scene's instance data, read at device addresses (levels::InstanceRecord).
//! layout(set = 0, binding = 3, std430) readonly buffer Instances { InstanceData instances[]; };
//! ```
//!
//! Through vkrt, binding 0 is a uniform texel buffer (RGBA32UI) whose first texel's `.xy`
//! is the top level's handle address ([`TopLevel::handle_address`], low word first);
//! through the driver it is the driver's top-level structure.
//!
//! [`TopLevel::handle_address`]: crate::accel::instances::TopLevel::handle_address

pub mod compare;
pub mod compile;
pub mod levels;
pub mod reflect;

use std::path::Path;

use crate::accel::device::AccelChoice;
use crate::accel::shader_library::{
    steps_specialization, LOOP_BUDGET_CONSTANT_ID, STEPS_CONSTANT_ID,
};
use crate::gpu::{Buffer, Context, ForeignBinding, ForeignKernel, GpuError, Recorder, TexelView};
use crate::scene::Scene;
use crate::trace::Ray;
use levels::SceneLevels;
use reflect::{BindingKind, ShaderInterface};

/// Which ray queries answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Through {
    /// vkrt's and the driver's (vkrt's alone where the device has no ray query).
    Both,
    /// vkrt's alone.
    Vkrt,
    /// The driver's alone.
    Driver,
}

/// Why a check could not run.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// The shader does not compile.
    #[error(transparent)]
    Compile(#[from] compile::CompileError),
    /// The shader breaks the interface.
    #[error("{shader}: {reason}")]
    Interface {
        /// The shader's path.
        shader: String,
        /// What is wrong.
        reason: String,
    },
    /// The device cannot run it.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The SPIR-V pass refused the module.
    #[error("{shader}: the SPIR-V pass: {error}")]
    Lower {
        /// The shader's path.
        shader: String,
        /// Why.
        error: crate::spirv::LowerError,
    },
}

/// A shader compiled for both paths, its interfaces checked.
pub struct CompiledShader {
    /// Through vkrt (with the include), where asked for.
    pub vkrt: Option<(Vec<u32>, ShaderInterface)>,
    /// With `VKRT_NATIVE_RAY_QUERY=1` (the driver's ray query), where asked for.
    pub native: Option<(Vec<u32>, ShaderInterface)>,
    /// Whether the include line was inserted.
    pub inserted_include: bool,
}

/// Compiles `source` (the file `shader`) for the paths `through` asks for, with vkrt's
/// include files written to `include`, and checks each variant's interface.
pub fn compile_shader(
    shader: &Path,
    source: &str,
    include: &Path,
    through: Through,
) -> Result<CompiledShader, CheckError> {
    let (source, inserted_include) = compile::with_include(source);
    let variant = |native: bool| -> Result<(Vec<u32>, ShaderInterface), CheckError> {
        let words = compile::compile(shader, &source, include, native)?;
        let iface = reflect::reflect(&words).map_err(|e| CheckError::Interface {
            shader: shader.display().to_string(),
            reason: e.to_string(),
        })?;
        check_interface(&iface, native).map_err(|reason| CheckError::Interface {
            shader: shader.display().to_string(),
            reason,
        })?;
        Ok((words, iface))
    };
    Ok(CompiledShader {
        vkrt: (through != Through::Driver)
            .then(|| variant(false))
            .transpose()?,
        native: (through != Through::Vkrt)
            .then(|| variant(true))
            .transpose()?,
        inserted_include,
    })
}

/// The driver's variant `native` (SPIR-V that uses the driver's ray query, from any
/// compiler) lowered by the SPIR-V pass ([`crate::spirv`]) to run through vkrt, its
/// interface checked: what `vkrt shader-check --via pass` and a `.spv` shader run.
pub fn lower_shader(
    shader: &Path,
    native: &[u32],
) -> Result<(Vec<u32>, ShaderInterface), CheckError> {
    lower_shader_with(shader, native, &crate::spirv::LowerOptions::default())
}

/// [`lower_shader`] with `options` (the device's: `LowerOptions::for_device`).
pub fn lower_shader_with(
    shader: &Path,
    native: &[u32],
    options: &crate::spirv::LowerOptions,
) -> Result<(Vec<u32>, ShaderInterface), CheckError> {
    let interface = |reason: String| CheckError::Interface {
        shader: shader.display().to_string(),
        reason,
    };
    let lowered =
        crate::spirv::lower_ray_queries(native, options).map_err(|error| CheckError::Lower {
            shader: shader.display().to_string(),
            error,
        })?;
    if !lowered.changed {
        return Err(interface(
            "it has no ray query (no RayQueryKHR capability)".into(),
        ));
    }
    let iface = reflect::reflect(&lowered.words).map_err(|e| interface(e.to_string()))?;
    check_interface(&iface, false).map_err(interface)?;
    Ok((lowered.words, iface))
}

/// SPIR-V for the driver's ray query (a `.spv` file), its interface checked.
pub fn native_shader(
    shader: &Path,
    words: Vec<u32>,
) -> Result<(Vec<u32>, ShaderInterface), CheckError> {
    let interface = |reason: String| CheckError::Interface {
        shader: shader.display().to_string(),
        reason,
    };
    let iface = reflect::reflect(&words).map_err(|e| interface(e.to_string()))?;
    check_interface(&iface, true).map_err(interface)?;
    Ok((words, iface))
}

/// Why `iface` (compiled through vkrt, or for the driver's ray query where `native`) breaks
/// the command's interface.
pub fn check_interface(iface: &ShaderInterface, native: bool) -> Result<(), String> {
    if !iface.compute_main {
        return Err("no compute entry point `main`".into());
    }
    match iface.local_size {
        Some([x, 1, 1]) if x >= 1 => {}
        // Two-dimensional: an image's pixels, the push block's second word its width.
        Some([x, y, 1]) if x >= 1 && y > 1 => {
            if iface.push_constants.is_none_or(|(bytes, _)| bytes < 8) {
                return Err(format!(
                    "its workgroup is two-dimensional ({x} x {y}): its push-constant block \
                     must hold the ray count and then the image's width, \
                     layout(push_constant) uniform Count {{ uint rayCount; uint width; }};"
                ));
            }
        }
        Some(s) => {
            return Err(format!(
                "its workgroup size is {s:?}: give a one-dimensional one, \
                 layout(local_size_x = N) in; (one invocation per ray), or a two-dimensional \
                 one over an image (local_size_x and local_size_y)"
            ))
        }
        None => return Err("it declares no workgroup size".into()),
    }
    let at = |b: u32| iface.bindings.iter().find(|x| x.set == 0 && x.binding == b);
    if let Some(extra) = iface.bindings.iter().find(|b| b.set != 0 || b.binding > 3) {
        return Err(format!(
            "it declares set {} binding {}{}: the command binds set 0 bindings 0 \
             (the structure), 1 (the rays), 2 (the results) and 3 (the instance data) only",
            extra.set,
            extra.binding,
            name_of(extra)
        ));
    }
    if let Some(kind) = at(3).map(|b| b.kind) {
        if !matches!(kind, BindingKind::StorageBuffer { .. }) {
            return Err(format!(
                "set 0 binding 3 is {}: it must be a storage buffer of the instance data, \
                 readonly buffer Instances {{ InstanceData instances[]; }}",
                kind.describe()
            ));
        }
    }
    let structure = at(0).map(|b| b.kind);
    match (native, structure) {
        (true, Some(BindingKind::AccelerationStructure)) => {}
        (false, Some(BindingKind::UniformTexelBuffer)) => {}
        (false, Some(BindingKind::AccelerationStructure)) if iface.uses_ray_query => {
            return Err(format!(
                "through vkrt it still uses the driver's ray query at set 0 binding 0: \
                 include \"{}\" after the #extension lines, and nothing that redefines it",
                compile::INCLUDE
            ))
        }
        (_, Some(kind)) => {
            return Err(format!(
                "set 0 binding 0 is {}: declare the structure there, \
                 layout(set = 0, binding = 0) uniform accelerationStructureEXT NAME;",
                kind.describe()
            ))
        }
        (_, None) => {
            return Err("set 0 binding 0 is missing: declare the structure there, \
                 layout(set = 0, binding = 0) uniform accelerationStructureEXT NAME;"
                .into())
        }
    }
    for (b, what) in [(1, "rays: vec4 rays[]"), (2, "results: uvec4 results[]")] {
        match at(b).map(|x| x.kind) {
            Some(BindingKind::StorageBuffer { vec4_array: true }) => {}
            Some(kind) => {
                return Err(format!(
                    "set 0 binding {b} is {}: it must be a storage buffer of the {what}",
                    kind.describe()
                ))
            }
            None => {
                return Err(format!(
                    "set 0 binding {b} is missing: declare the {what} there"
                ))
            }
        }
    }
    match iface.push_constants {
        Some((bytes, true)) if bytes >= 4 => Ok(()),
        Some((bytes, _)) => Err(format!(
            "its push-constant block ({bytes} bytes) does not start with a 32-bit integer \
             (the ray count): layout(push_constant) uniform Count {{ uint rayCount; }};"
        )),
        None => Err("it has no push-constant block for the ray count: \
                     layout(push_constant) uniform Count { uint rayCount; };"
            .into()),
    }
}

fn name_of(b: &reflect::Binding) -> String {
    b.name
        .as_ref()
        .map_or_else(String::new, |n| format!(" (`{n}`)"))
}

/// What one path wrote and how long its dispatch took on the GPU.
pub struct PathRun {
    /// 16 bytes a ray, as the shader wrote them (zero where it wrote nothing).
    pub results: Vec<[u32; 4]>,
    /// The dispatch's GPU milliseconds (`None` without timestamps).
    pub ms: Option<f64>,
}

/// Runs `spirv` (its interface `iface`) over `rays` through vkrt's two levels of `scene`
/// (bottom levels of `choice`'s kind, with 4-wide nodes where its walk is the wide one),
/// the include's loop-budget walk chosen as the device needs it
/// ([`LOOP_BUDGET_CONSTANT_ID`]).
pub fn run_vkrt(
    ctx: &Context,
    levels: &SceneLevels,
    choice: AccelChoice,
    shader: (&[u32], &ShaderInterface),
    rays: &[Ray],
) -> Result<PathRun, GpuError> {
    let loop_budget_walk = ctx.info().loop_budget.is_some();
    run_vkrt_walking(ctx, levels, choice, shader, rays, loop_budget_walk)
}

/// [`run_vkrt`] with the include's loop-budget walk on or off, whatever the device
/// ([`LOOP_BUDGET_CONSTANT_ID`], where the shader declares it).
pub fn run_vkrt_walking(
    ctx: &Context,
    levels: &SceneLevels,
    choice: AccelChoice,
    (spirv, iface): (&[u32], &ShaderInterface),
    rays: &[Ray],
    loop_budget_walk: bool,
) -> Result<PathRun, GpuError> {
    let f = &ctx.info().features;
    if !(f.buffer_device_address && f.shader_int64) {
        return Err(GpuError::MissingCapability {
            device: ctx.info().device.clone(),
            what: "bufferDeviceAddress and shaderInt64 (vkrt's top level is read at device \
                   addresses)"
                .into(),
        });
    }
    let mut rec = Recorder::new(ctx)?;
    let built = rec.scope("build", |rec| levels.record_vkrt(rec, choice))?;
    let address = built.top.handle_address();
    let handle = Buffer::<[u32; 4]>::new(ctx, "shader_check.handle", 1)?;
    rec.upload(&handle, &[[address as u32, (address >> 32) as u32, 0, 0]])?;
    let view = TexelView::new(ctx, &handle)?;
    let steps = ctx.info().max_traversal_steps;
    let mut spec = Vec::new();
    if iface.spec_ids.contains(&STEPS_CONSTANT_ID) {
        let (entry, data) = steps_specialization(steps);
        spec.push((entry[0].constant_id, u32::from_ne_bytes(data)));
    }
    if iface.spec_ids.contains(&LOOP_BUDGET_CONSTANT_ID) {
        spec.push((LOOP_BUDGET_CONSTANT_ID, u32::from(loop_budget_walk)));
    }
    let out = dispatch(
        ctx,
        rec,
        (spirv, iface),
        ForeignBinding::Texel(&view),
        levels,
        &spec,
        rays,
    )?;
    drop(built);
    Ok(out)
}

/// Runs `spirv` (its interface `iface`) over `rays` through the driver's two levels of the
/// scene. Needs the driver's ray query.
pub fn run_driver(
    ctx: &Context,
    levels: &SceneLevels,
    (spirv, iface): (&[u32], &ShaderInterface),
    rays: &[Ray],
) -> Result<PathRun, GpuError> {
    crate::gpu::require_ray_query(ctx)?;
    let mut rec = Recorder::new(ctx)?;
    let built = rec.scope("build", |rec| levels.record_driver(rec))?;
    let out = dispatch(
        ctx,
        rec,
        (spirv, iface),
        ForeignBinding::Accel(built.accel.tlas()),
        levels,
        &[],
        rays,
    )?;
    drop(built);
    Ok(out)
}

/// Records the rays' upload (and the instance data's, where the shader declares binding 3),
/// the shader's dispatch (timed in a scope `shader`) and the results' read-back after what
/// `rec` holds, submits and waits.
fn dispatch(
    ctx: &Context,
    mut rec: Recorder,
    (spirv, iface): (&[u32], &ShaderInterface),
    structure: ForeignBinding<'_>,
    levels: &SceneLevels,
    spec: &[(u32, u32)],
    rays: &[Ray],
) -> Result<PathRun, GpuError> {
    let n = rays.len();
    let ray_buf = Buffer::<Ray>::new(ctx, "shader_check.rays", n)?;
    let results = Buffer::<[u32; 4]>::new(ctx, "shader_check.results", n)?;
    rec.upload(&ray_buf, rays)?;
    rec.fill(&results, 0);
    let wants_instances = iface.bindings.iter().any(|b| b.set == 0 && b.binding == 3);
    let instances = wants_instances
        .then(|| levels.record_instance_data(&mut rec))
        .transpose()?;
    rec.transfer_to_compute();
    let (push_bytes, _) = iface.push_constants.unwrap_or((4, true));
    let push_bytes = push_bytes.next_multiple_of(4);
    let mut bindings = vec![
        structure,
        ForeignBinding::Storage(&ray_buf),
        ForeignBinding::Storage(&results),
    ];
    if let Some(data) = &instances {
        bindings.push(ForeignBinding::Storage(&data.records));
    }
    let kernel = ForeignKernel::new(ctx, "shader-check", spirv, &bindings, push_bytes, spec)?;
    let mut push = vec![0u8; push_bytes as usize];
    let [lx, ly, _] = iface
        .local_size
        .unwrap_or([1, 1, 1])
        .map(|v| u64::from(v.max(1)));
    // One-dimensional: a workgroup per `lx` rays. Two-dimensional: the rays are an image's
    // rows of `width`, `lx` by `ly` pixels a workgroup, and the width is the second word.
    let groups = if ly > 1 {
        let width = iface
            .grid_width
            .filter(|w| *w > 0)
            .ok_or_else(|| GpuError::Usage {
                call: "shader_check::run",
                reason: "a two-dimensional shader needs the image's width (--width)".into(),
            })?;
        push[4..8].copy_from_slice(&width.to_le_bytes());
        let rows = (n as u64).div_ceil(u64::from(width));
        [u64::from(width).div_ceil(lx), rows.div_ceil(ly)]
    } else {
        [(n as u64).div_ceil(lx), 1]
    };
    // A driver may compile a pipeline's code at its first dispatch (lavapipe does): one
    // group over no rays first, untimed, so that the timed dispatch is the shader's work.
    rec.scope("compile", |rec| kernel.record_dispatch(rec, 1, &push))?;
    rec.compute_to_compute();
    push[..4].copy_from_slice(&(n as u32).to_le_bytes());
    rec.scope("shader", |rec| {
        kernel.record_dispatch_grid(rec, groups, &push)
    })?;
    rec.compute_to_transfer();
    let back = rec.read_back(&results)?;
    rec.transfer_to_host();
    let profile = rec.submit_and_wait()?;
    let results = back.read()?;
    drop(kernel);
    drop(instances);
    Ok(PathRun {
        results,
        ms: profile.ms("shader"),
    })
}

/// The rays whose records differ, in order: (ray, driver's record, vkrt's record).
pub fn mismatches(driver: &[[u32; 4]], vkrt: &[[u32; 4]]) -> Vec<(usize, [u32; 4], [u32; 4])> {
    driver
        .iter()
        .zip(vkrt)
        .enumerate()
        .filter(|(_, (d, v))| !compare::records_agree(d, v))
        .map(|(i, (d, v))| (i, *d, *v))
        .collect()
}

/// The scene's levels at its shutter-open time (the time `vkrt trace` places it at).
pub fn scene_levels(scene: &Scene) -> SceneLevels {
    SceneLevels::of(scene, scene.camera.shutter_open)
}
