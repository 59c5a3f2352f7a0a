//! The SPIR-V pass (`vkrt::spirv::lower_ray_queries`) on the shapes real shaders take,
//! compiled by glslang (glslc) for every stage (compute, fragment, vertex, geometry,
//! tessellation, mesh and task) and SPIR-V version the pass takes: every
//! rewrite passes `spirv-val` for its Vulkan version and keeps no ray-query instruction,
//! capability or extension; query handles are numbered statically; bad input is an error
//! naming the instruction and its word offset, never a panic. What the lowered shaders
//! compute is checked on the device in `ray_query_families.rs` and `cli_shader_check.rs`.

use std::path::PathBuf;
use std::process::Command;

use rspirv::spirv::{Capability, Op};
use vkrt::spirv::{lower_ray_queries, LowerError, LowerOptions};

fn scratch() -> PathBuf {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let dir = std::env::temp_dir().join(format!(
        "vkrt-spirv-lower-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn words_of(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// `source` compiled by glslc for `stage` and `env` (vulkan1.1 + spv1.3, vulkan1.2, ...).
fn glslc(source: &str, stage: &str, target: &[&str]) -> Vec<u32> {
    let dir = scratch();
    let src = dir.join("shader.glsl");
    let out = dir.join("shader.spv");
    std::fs::write(&src, source).unwrap();
    let result = Command::new(vkrt::shader_check::compile::compiler())
        .arg(format!("-fshader-stage={stage}"))
        .args(target)
        .arg("-o")
        .arg(&out)
        .arg(&src)
        .output()
        .expect("glslc (./x setup installs it)");
    assert!(
        result.status.success(),
        "glslc: {}",
        String::from_utf8_lossy(&result.stderr)
    );
    let words = words_of(&std::fs::read(&out).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    words
}

/// `spirv-val` over `words` for `env`; its message where it refuses them.
fn spirv_val(words: &[u32], env: &str) -> Result<(), String> {
    let dir = scratch();
    let path = dir.join("lowered.spv");
    std::fs::write(&path, bytemuck::cast_slice(words)).unwrap();
    let result = Command::new("spirv-val")
        .arg("--target-env")
        .arg(env)
        .arg(&path)
        .output()
        .expect("spirv-val (Debian's spirv-tools; ./x setup installs it)");
    let _ = std::fs::remove_dir_all(&dir);
    if result.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&result.stderr).into_owned()
            + &String::from_utf8_lossy(&result.stdout))
    }
}

fn dis(words: &[u32]) -> String {
    let dir = scratch();
    let path = dir.join("m.spv");
    std::fs::write(&path, bytemuck::cast_slice(words)).unwrap();
    let out = Command::new("spirv-dis").arg(&path).output().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The opcodes and capabilities of a module.
fn contents(words: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let mut ops = Vec::new();
    let mut caps = Vec::new();
    let mut i = 5;
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let op = words[i] & 0xffff;
        if op == Op::Capability as u32 {
            caps.push(words[i + 1]);
        }
        ops.push(op);
        i += count.max(1);
    }
    (ops, caps)
}

const RAY_QUERY_OPS: [Op; 6] = [
    Op::TypeRayQueryKHR,
    Op::TypeAccelerationStructureKHR,
    Op::RayQueryInitializeKHR,
    Op::RayQueryProceedKHR,
    Op::RayQueryGetIntersectionTypeKHR,
    Op::ConvertUToAccelerationStructureKHR,
];

/// Lowers `words`, checks the result with spirv-val for `env`, and that nothing of the
/// ray-query extension is left.
fn lower_valid(name: &str, words: &[u32], env: &str) -> vkrt::spirv::Lowered {
    let lowered = lower_ray_queries(words, &LowerOptions::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(lowered.changed, "{name}");
    if let Err(e) = spirv_val(&lowered.words, env) {
        panic!(
            "{name}: spirv-val refuses the lowered module:\n{e}\n{}",
            dis(&lowered.words)
        );
    }
    let (ops, caps) = contents(&lowered.words);
    for op in RAY_QUERY_OPS {
        assert!(!ops.contains(&(op as u32)), "{name}: {op:?} is left");
    }
    for cap in [
        Capability::RayQueryKHR,
        Capability::RayTraversalPrimitiveCullingKHR,
    ] {
        assert!(
            !caps.contains(&(cap as u32)),
            "{name}: capability {cap:?} is left"
        );
    }
    // The walk for a device with a loop budget: another loop, as valid.
    let budget = LowerOptions {
        loop_budget: true,
        ..LowerOptions::default()
    };
    let flat = lower_ray_queries(words, &budget).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_ne!(
        flat.words, lowered.words,
        "{name}: loop_budget changed nothing"
    );
    if let Err(e) = spirv_val(&flat.words, env) {
        panic!(
            "{name}: spirv-val refuses the module lowered for a loop budget:\n{e}\n{}",
            dis(&flat.words)
        );
    }
    lowered
}

const HEADER: &str = "#version 460\n#extension GL_EXT_ray_query : require\n";

/// Every instruction of the extension, in a compute shader.
const EVERY_INSTRUCTION: &str = r#"
layout(local_size_x = 8) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) buffer Out { vec4 v[]; };
layout(constant_id = 7) const float SCALE = 1.0;
void main() {
    uint i = gl_GlobalInvocationID.x;
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, 0xff, vec3(0.0), 0.0, vec3(0.0, 0.0, 1.0), 100.0);
    vec4 acc = vec4(0.0);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {
            acc.x += rayQueryGetIntersectionTEXT(q, false);
            acc.yz += rayQueryGetIntersectionBarycentricsEXT(q, false);
            if (rayQueryGetIntersectionFrontFaceEXT(q, false)) rayQueryConfirmIntersectionEXT(q);
        } else {
            if (rayQueryGetIntersectionCandidateAABBOpaqueEXT(q)) rayQueryGenerateIntersectionEXT(q, 1.0);
            else rayQueryTerminateEXT(q);
        }
    }
    acc.x += float(rayQueryGetIntersectionInstanceCustomIndexEXT(q, true));
    acc.x += float(rayQueryGetIntersectionInstanceIdEXT(q, true));
    acc.x += float(rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(q, true));
    acc.x += float(rayQueryGetIntersectionGeometryIndexEXT(q, true));
    acc.x += float(rayQueryGetIntersectionPrimitiveIndexEXT(q, true));
    acc.xyz += rayQueryGetIntersectionObjectRayDirectionEXT(q, true);
    acc.xyz += rayQueryGetIntersectionObjectRayOriginEXT(q, true);
    acc.xyz += rayQueryGetIntersectionObjectToWorldEXT(q, true)[3];
    acc.xyz += rayQueryGetIntersectionWorldToObjectEXT(q, true)[2];
    acc.x += rayQueryGetRayTMinEXT(q) + float(rayQueryGetRayFlagsEXT(q));
    acc.xyz += rayQueryGetWorldRayOriginEXT(q) + rayQueryGetWorldRayDirectionEXT(q);
    acc.w = float(rayQueryGetIntersectionTypeEXT(q, true)) * SCALE;
    v[i] = acc;
}
"#;

/// A query initialized in a helper, queries in arrays and loops, a query passed on.
const HELPERS_AND_ARRAYS: &str = r#"
layout(local_size_x = 8) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scenes[3];
layout(set = 0, binding = 1, std430) buffer Out { uint v[]; };
layout(push_constant) uniform P { uint64_t address; uvec2 words; };
void start(rayQueryEXT q, uint k) {
    rayQueryInitializeEXT(q, scenes[k], gl_RayFlagsOpaqueEXT, 0xff, vec3(float(k)), 0.0, vec3(0.0, 0.0, 1.0), 10.0);
}
bool hits(rayQueryEXT q) {
    while (rayQueryProceedEXT(q)) {}
    rayQueryEXT inner;
    rayQueryInitializeEXT(inner, accelerationStructureEXT(address), 0u, 0xff, vec3(0.0), 0.0, vec3(1.0, 0.0, 0.0), 10.0);
    rayQueryProceedEXT(inner);
    return rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT
        && rayQueryGetIntersectionTypeEXT(inner, true) == gl_RayQueryCommittedIntersectionNoneEXT;
}
void main() {
    rayQueryEXT qs[3];
    uint n = 0u;
    for (uint k = 0u; k < 3u; k++) {
        start(qs[k], k);
        n += hits(qs[k]) ? 1u : 0u;
    }
    for (uint r = 0u; r < 2u; r++) {
        rayQueryEXT again;
        rayQueryInitializeEXT(again, accelerationStructureEXT(words), 0u, 0xff, vec3(0.0), 0.0, vec3(0.0, 1.0, 0.0), 5.0);
        n += rayQueryProceedEXT(again) ? 1u : 0u;
    }
    v[gl_GlobalInvocationID.x] = n;
}
"#;

/// A runtime array of structures indexed non-uniformly.
const BINDLESS: &str = r#"
#extension GL_EXT_nonuniform_qualifier : require
layout(local_size_x = 8) in;
layout(set = 1, binding = 3) uniform accelerationStructureEXT scenes[];
layout(set = 0, binding = 1, std430) buffer Out { float v[]; };
void main() {
    uint k = gl_GlobalInvocationID.x;
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scenes[nonuniformEXT(k)], 0u, 0xff, vec3(0.0), 0.0, vec3(0.0, 0.0, 1.0), 10.0);
    rayQueryProceedEXT(q);
    v[k] = rayQueryGetIntersectionTEXT(q, true);
}
"#;

/// A fragment shader's shadow query with an alpha-tested candidate loop.
const FRAGMENT: &str = r#"
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(location = 0) in vec3 position;
layout(location = 0) out vec4 color;
void main() {
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsTerminateOnFirstHitEXT, 0xff, position, 0.001, vec3(0.0, 1.0, 0.0), 1e30);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionBarycentricsEXT(q, false).x < 0.5) rayQueryConfirmIntersectionEXT(q);
    }
    bool lit = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT;
    color = vec4(lit ? 1.0 : 0.2);
}
"#;

/// A vertex shader's query.
const VERTEX: &str = r#"
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(location = 0) in vec3 position;
layout(location = 0) out float visible;
void main() {
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsOpaqueEXT, 0xff, position, 0.0, vec3(0.0, 0.0, -1.0), 100.0);
    rayQueryProceedEXT(q);
    visible = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT ? 1.0 : 0.0;
    gl_Position = vec4(position, 1.0);
}
"#;

/// A geometry shader's query per vertex, in a loop.
const GEOMETRY: &str = r#"
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
void main() {
    for (int k = 0; k < 3; k++) {
        rayQueryEXT q;
        rayQueryInitializeEXT(q, scene, 0u, 0xff, gl_in[k].gl_Position.xyz, 0.0, vec3(0, 0, 1), 10.0);
        rayQueryProceedEXT(q);
        gl_Position = gl_in[k].gl_Position + vec4(0, 0, rayQueryGetIntersectionTEXT(q, true), 0);
        EmitVertex();
    }
    EndPrimitive();
}
"#;

/// A tessellation evaluation shader's query.
const TESSELLATION: &str = r#"
layout(triangles) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
void main() {
    vec3 p = gl_TessCoord.x * gl_in[0].gl_Position.xyz + gl_TessCoord.y * gl_in[1].gl_Position.xyz
        + gl_TessCoord.z * gl_in[2].gl_Position.xyz;
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsOpaqueEXT, 0xff, p, 0.0, vec3(0, 1, 0), 10.0);
    rayQueryProceedEXT(q);
    gl_Position = vec4(p, rayQueryGetIntersectionTypeEXT(q, true) == 0u ? 1.0 : 2.0);
}
"#;

/// A mesh shader's query (`GL_EXT_mesh_shader`).
const MESH: &str = r#"
#extension GL_EXT_mesh_shader : require
layout(local_size_x = 1) in;
layout(triangles, max_vertices = 3, max_primitives = 1) out;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
void main() {
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, 0u, 0xff, vec3(0), 0.0, vec3(0, 0, 1), 10.0);
    rayQueryProceedEXT(q);
    float z = rayQueryGetIntersectionTypeEXT(q, true) == 0u ? 0.0 : 1.0;
    SetMeshOutputsEXT(3, 1);
    gl_MeshVerticesEXT[0].gl_Position = vec4(0, 0, z, 1);
    gl_MeshVerticesEXT[1].gl_Position = vec4(1, 0, z, 1);
    gl_MeshVerticesEXT[2].gl_Position = vec4(0, 1, z, 1);
    gl_PrimitiveTriangleIndicesEXT[0] = uvec3(0, 1, 2);
}
"#;

/// A task shader's query deciding how many mesh groups to launch.
const TASK: &str = r#"
#extension GL_EXT_mesh_shader : require
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
void main() {
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, 0u, 0xff, vec3(0), 0.0, vec3(0, 0, 1), 10.0);
    rayQueryProceedEXT(q);
    EmitMeshTasksEXT(rayQueryGetIntersectionTypeEXT(q, true) == 0u ? 0u : 1u, 1u, 1u);
}
"#;

/// `layout(primitive_culling)`, and a ray flag that skips triangles.
const CULLING: &str = r#"
#extension GL_EXT_ray_flags_primitive_culling : require
layout(primitive_culling);
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) buffer Out { uint v[]; };
void main() {
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsSkipTrianglesEXT, 0xff, vec3(0.0), 0.0, vec3(0.0, 0.0, 1.0), 10.0);
    rayQueryProceedEXT(q);
    v[0] = rayQueryGetIntersectionTypeEXT(q, true);
}
"#;

#[test]
fn every_rewrite_passes_spirv_val_in_every_stage_and_version() {
    let compute_targets: [(&[&str], &str); 4] = [
        (
            &["--target-env=vulkan1.1", "--target-spv=spv1.3"],
            "vulkan1.1",
        ),
        (
            &["--target-env=vulkan1.1", "--target-spv=spv1.4"],
            "vulkan1.1spv1.4",
        ),
        (&["--target-env=vulkan1.2"], "vulkan1.2"),
        (&["--target-env=vulkan1.3"], "vulkan1.3"),
    ];
    for (name, body) in [
        ("every_instruction", EVERY_INSTRUCTION),
        ("helpers_and_arrays", HELPERS_AND_ARRAYS),
        ("bindless", BINDLESS),
        ("culling", CULLING),
    ] {
        let source = if name == "helpers_and_arrays" {
            format!("{HEADER}#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require\n{body}")
        } else {
            format!("{HEADER}{body}")
        };
        for (target, env) in compute_targets {
            let words = glslc(&source, "compute", target);
            lower_valid(&format!("{name} ({env})"), &words, env);
        }
    }
    for (name, body, stage, env) in [
        ("fragment", FRAGMENT, "fragment", "vulkan1.2"),
        ("vertex", VERTEX, "vertex", "vulkan1.2"),
        ("geometry", GEOMETRY, "geometry", "vulkan1.2"),
        ("tessellation", TESSELLATION, "tesseval", "vulkan1.2"),
        ("mesh", MESH, "mesh", "vulkan1.3"),
        ("task", TASK, "task", "vulkan1.3"),
    ] {
        let target = format!("--target-env={env}");
        let words = glslc(&format!("{HEADER}{body}"), stage, &[&target]);
        lower_valid(name, &words, env);
    }
    // The Vulkan memory model.
    let source = format!("{HEADER}#pragma use_vulkan_memory_model\n{EVERY_INSTRUCTION}");
    let words = glslc(&source, "compute", &["--target-env=vulkan1.3"]);
    lower_valid("vulkan memory model", &words, "vulkan1.3");
}

#[test]
fn handles_are_numbered_from_the_static_count() {
    // main holds three queries and `again`; `hits` one more while main's are live: 5.
    let source = format!(
        "{HEADER}#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require\n{HELPERS_AND_ARRAYS}"
    );
    let words = glslc(&source, "compute", &["--target-env=vulkan1.2"]);
    let lowered = lower_valid("helpers_and_arrays", &words, "vulkan1.2");
    assert_eq!(lowered.query_states, 5);
    assert_eq!(lowered.structures, 1);
    let words = glslc(
        &format!("{HEADER}{EVERY_INSTRUCTION}"),
        "compute",
        &["--target-env=vulkan1.2"],
    );
    let lowered = lower_valid("every_instruction", &words, "vulkan1.2");
    assert_eq!(lowered.query_states, 1);
    // 19 getters (and the one asked twice), initialize, proceed, confirm, generate,
    // terminate, and the structure's load.
    assert!(lowered.instructions >= 25, "{}", lowered.instructions);
    // Only what the shader calls is linked: a shader of one getter links fewer functions.
    let small = glslc(
        &format!("{HEADER}{VERTEX}"),
        "vertex",
        &["--target-env=vulkan1.2"],
    );
    let small = lower_valid("vertex", &small, "vulkan1.2");
    assert!(small.functions_linked < lowered.functions_linked);
    // The specialization constants stay; the step cap is one more.
    let text = dis(&lowered.words);
    assert!(
        text.contains("SpecId 7"),
        "the shader's own specialization constant"
    );
    assert!(text.contains(&format!(
        "SpecId {}",
        LowerOptions::default().steps_constant_id
    )));
}

#[test]
fn a_module_without_ray_queries_comes_back_unchanged() {
    let words = glslc(
        "#version 460\nlayout(local_size_x = 1) in;\nlayout(std430, binding = 0) buffer B { uint v[]; };\nvoid main() { v[0] = 1u; }\n",
        "compute",
        &["--target-env=vulkan1.2"],
    );
    assert!(!vkrt::spirv::has_ray_queries(&words));
    let lowered = lower_ray_queries(&words, &LowerOptions::default()).unwrap();
    assert!(!lowered.changed);
    assert_eq!(lowered.words, words);
}

#[test]
fn bad_input_is_an_error_that_names_the_instruction_and_its_offset() {
    let words = glslc(
        &format!("{HEADER}{EVERY_INSTRUCTION}"),
        "compute",
        &["--target-env=vulkan1.2"],
    );
    let options = LowerOptions::default();
    // Not SPIR-V.
    assert!(matches!(
        lower_ray_queries(&[1, 2, 3, 4, 5, 6], &options),
        Err(LowerError::NotSpirv(_))
    ));
    assert!(matches!(
        lower_ray_queries(&[], &options),
        Err(LowerError::NotSpirv(_))
    ));
    let swapped: Vec<u32> = words.iter().map(|w| w.swap_bytes()).collect();
    assert!(
        matches!(lower_ray_queries(&swapped, &options), Err(LowerError::NotSpirv(m)) if m.contains("byte-swapped"))
    );
    // Truncated in the middle of an instruction (an OpLoad of 4 words).
    let load = find_op(&words, Op::Load).unwrap();
    match lower_ray_queries(&words[..load + 2], &options) {
        Err(LowerError::Malformed { offset, reason }) => {
            assert_eq!(offset, load);
            assert!(
                reason.contains("truncated") && reason.contains("OpLoad"),
                "{reason}"
            );
        }
        other => panic!("{other:?}"),
    }
    // SPIR-V 1.0.
    let mut old = words.clone();
    old[1] = 0x0001_0000;
    assert_eq!(
        lower_ray_queries(&old, &options).unwrap_err(),
        LowerError::Version { major: 1, minor: 0 }
    );
    // An id past the bound: the first OpLoad's pointer.
    let mut bad = words.clone();
    let at = find_op(&bad, Op::Load).unwrap();
    bad[at + 3] = bad[3] + 10;
    match lower_ray_queries(&bad, &options) {
        Err(LowerError::BadId {
            instruction,
            offset,
            ..
        }) => {
            assert_eq!(instruction, "OpLoad");
            assert_eq!(offset, at);
        }
        other => panic!("{other:?}"),
    }
    // The step cap's id taken by the shader's own constant.
    let taken = LowerOptions {
        steps_constant_id: 7,
        ..LowerOptions::default()
    };
    assert_eq!(
        lower_ray_queries(&words, &taken).unwrap_err(),
        LowerError::SpecIdTaken(7)
    );
    // A ray-tracing pipeline stage.
    let rgen = glslc(
        "#version 460\n#extension GL_EXT_ray_tracing : require\n#extension GL_EXT_ray_query : require\nlayout(set = 0, binding = 0) uniform accelerationStructureEXT s;\nlayout(location = 0) rayPayloadEXT vec4 p;\nvoid main() { rayQueryEXT q; rayQueryInitializeEXT(q, s, 0u, 0xff, vec3(0), 0.0, vec3(1), 1.0); traceRayEXT(s, 0u, 0xff, 0u, 0u, 0u, vec3(0), 0.0, vec3(1), 1.0, 0); }\n",
        "rgen",
        &["--target-env=vulkan1.2"],
    );
    match lower_ray_queries(&rgen, &options) {
        Err(LowerError::Unsupported {
            instruction,
            offset,
            reason,
        }) => {
            assert!(offset > 0);
            assert!(
                instruction.contains("RayTracingKHR") || instruction.contains("RayGeneration"),
                "{instruction}: {reason}"
            );
        }
        other => panic!("{other:?}"),
    }
}

/// A type that names itself (an array whose element is the array): an error, not a hang.
#[test]
fn a_cycle_of_types_is_refused() {
    let words = glslc(
        &format!("{HEADER}#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require\n{HELPERS_AND_ARRAYS}"),
        "compute",
        &["--target-env=vulkan1.2"],
    );
    let mut cyclic = words.clone();
    let mut i = 5;
    let mut patched = 0;
    while i < cyclic.len() {
        let count = (cyclic[i] >> 16) as usize;
        if cyclic[i] & 0xffff == Op::TypeArray as u32 {
            cyclic[i + 2] = cyclic[i + 1];
            patched += 1;
        }
        i += count.max(1);
    }
    assert!(patched > 0);
    assert!(lower_ray_queries(&cyclic, &LowerOptions::default()).is_err());
}

/// The word offset of the first instruction `op` inside a function.
fn find_op(words: &[u32], op: Op) -> Option<usize> {
    let mut i = 5;
    let mut in_function = false;
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let o = words[i] & 0xffff;
        if o == Op::Function as u32 {
            in_function = true;
        }
        if in_function && o == op as u32 {
            return Some(i);
        }
        i += count.max(1);
    }
    None
}

/// Random damage to a real module: every result is a module or an error, never a panic.
#[test]
fn damaged_modules_never_panic() {
    let words = glslc(
        &format!("{HEADER}#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require\n{HELPERS_AND_ARRAYS}"),
        "compute",
        &["--target-env=vulkan1.2"],
    );
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let rounds = if std::env::var_os("VKRT_TEST_QUICK").is_some() {
        300
    } else {
        1500
    };
    for _ in 0..rounds {
        let mut w = words.clone();
        match next() % 4 {
            0 => {
                let n = 1 + (next() % 4) as usize;
                for _ in 0..n {
                    let at = 5 + (next() as usize) % (w.len() - 5);
                    w[at] = next() as u32;
                }
            }
            1 => {
                let at = 5 + (next() as usize) % (w.len() - 5);
                w[at] ^= 1 << (next() % 32);
            }
            2 => {
                let at = 5 + (next() as usize) % (w.len() - 5);
                w.truncate(at);
            }
            _ => {
                // An id operand pointed somewhere else in the bound.
                let at = 5 + (next() as usize) % (w.len() - 5);
                w[at] = 1 + (next() as u32) % w[3];
            }
        }
        let _ = lower_ray_queries(&w, &LowerOptions::default());
    }
}
