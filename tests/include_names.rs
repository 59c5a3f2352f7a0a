//! `vkrt/ray_query.glsl` cannot clash with the includer's names: every name the library
//! declares carries the `vkrt`/`Vkrt`/`VKRT_` prefix, and a renderer's shader that declares
//! common names of its own after the include compiles in every mode of the library. Also
//! what each mode asks of the device, read from the SPIR-V it compiles to.

mod common;

use vkrt::accel::shader_library::FILES;

/// Whether `name` carries the library's prefix.
fn prefixed(name: &str) -> bool {
    name.starts_with("vkrt") || name.starts_with("Vkrt") || name.starts_with("VKRT_")
}

/// The first identifier at the start of `s`.
fn ident(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// Names declared at file scope in `source`: macros, functions, structs, blocks and their
/// instance names, constants. File scope is read as column 0, which the library keeps to.
fn declared_names(source: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut in_comment = false;
    for raw in source.lines() {
        let mut line = raw;
        if in_comment {
            match line.find("*/") {
                Some(end) => {
                    in_comment = false;
                    line = &line[end + 2..];
                }
                None => continue,
            }
        }
        if let Some(start) = line.find("/*") {
            in_comment = !line[start..].contains("*/");
            line = &line[..start];
        }
        let line = line.split("//").next().unwrap_or("");
        if let Some(rest) = line.trim_start().strip_prefix("#define") {
            names.push(ident(rest.trim_start()).to_string());
            continue;
        }
        if line.starts_with(' ') || line.starts_with('\t') || line.starts_with('#') {
            continue;
        }
        if let Some(rest) = line.strip_prefix('}') {
            let name = ident(rest.trim_start());
            if !name.is_empty() {
                names.push(name.to_string());
            }
            continue;
        }
        // Drop a layout qualifier, then read `[qualifiers] type name` up to `(`, `=`, `{`,
        // `[` or `;`.
        let mut decl = line;
        if let Some(rest) = decl.strip_prefix("layout") {
            match rest.find(')') {
                Some(close) => decl = &rest[close + 1..],
                None => continue,
            }
        }
        let head = decl
            .split(['(', '=', '{', '[', ';'])
            .next()
            .unwrap_or("")
            .trim();
        let words: Vec<&str> = head.split_whitespace().collect();
        match words.as_slice() {
            [.., "struct", name] | [.., "buffer", name] => names.push(name.to_string()),
            [_, .., name] if !decl.trim().is_empty() => names.push(ident(name).to_string()),
            _ => {}
        }
    }
    names.retain(|n| !n.is_empty());
    names
}

#[test]
fn every_name_the_library_declares_carries_its_prefix() {
    let mut unprefixed = Vec::new();
    let mut seen = 0;
    for (file, source) in FILES {
        for name in declared_names(source) {
            seen += 1;
            // `vkrt/ext_ray_query.glsl` defines the extension's own names, and a
            // constructor macro on a type that has none.
            let extension = *file == "vkrt/ext_ray_query.glsl"
                && ((name.starts_with("rayQuery") && name.ends_with("EXT"))
                    || name == "accelerationStructureEXT"
                    || name == "utextureBuffer");
            if !prefixed(&name) && !extension {
                unprefixed.push(format!("{file}: {name}"));
            }
        }
    }
    // The scan reads declarations: the library has well over a hundred.
    assert!(
        seen > 100,
        "only {seen} declarations found: the scan is broken"
    );
    assert!(
        unprefixed.is_empty(),
        "unprefixed names:\n{}",
        unprefixed.join("\n")
    );
}

#[test]
fn the_scan_finds_what_it_must() {
    let src = "#define NO_HIT 1u\nstruct Ray { vec3 o; };\nlayout(std430, binding = 0) \
               readonly buffer Spheres { vec4 spheres[]; };\nlayout(std430) buffer B {\n    \
               uint x;\n} scene_info;\nconst float FLT_MIN = 1.0;\nlayout(constant_id = 3) \
               const uint STACK = 1u;\nbool is_nan(float x) {\n    float local = x;\n    \
               return x != x;\n}\nuint tri_verts[4];\n";
    let names = declared_names(src);
    for want in [
        "NO_HIT",
        "Ray",
        "Spheres",
        "B",
        "scene_info",
        "FLT_MIN",
        "STACK",
        "is_nan",
        "tri_verts",
    ] {
        assert!(names.iter().any(|n| n == want), "{want} not in {names:?}");
    }
    assert!(!names.iter().any(|n| n == "local" || n == "x"), "{names:?}");
}

/// A renderer's shader: after the include, names of its own that a library without
/// prefixes would have taken (macros, constants, types, blocks, globals, functions).
const RENDERER_SHADER: &str = r#"#version 460
#extension GL_EXT_scalar_block_layout : enable
#define VKRT_SET 1
#include "vkrt/ray_query.glsl"

#define NO_HIT 0xfffffffeu
#define KD_LEAF 3u
#define NO_NODE 7u
#define DEAD 9u
#define FP64_FALLBACK 0
#define GEOM_BINDING 5
#define TEXEL_NODES 2
#define INTERSECT_WATERTIGHT 4u
const float FLT_MIN = 1.0e-30;
const float PI = 3.14159265;
const float INF = 1.0 / 0.0;
const uint STACK_SIZE = 8u;
const uint INTERSECTOR = 1u;
const uint MAX_TRAVERSAL_STEPS = 10u;
struct Ray { vec3 o; vec3 d; };
struct Hit { float t; uint id; };
struct KdNode { uint a; };
struct WideNode { uint b; };
struct Shear { vec3 s; };
struct MotionRecord { vec4 v; };
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) buffer Spheres { vec4 spheres[]; };
layout(set = 0, binding = 1) buffer Motions { vec4 motions[]; };
layout(set = 0, binding = 2) buffer TriVerts { float tri_verts[]; };
layout(set = 0, binding = 3) buffer Out { vec4 results[]; } scene_info;
uint kd_nodes[2];
float dot3(vec3 a, vec3 b) { return dot(a, b); }
bool is_nan(float x) { return x != x; }
bool is_finite(float x) { return !isinf(x) && !is_nan(x); }
uint primitive_count() { return 3u; }
bool hit_sphere(Ray r) { return dot3(r.o, r.d) > FLT_MIN; }
Hit trace_ray(Ray r) { return Hit(INF, NO_HIT); }
vec3 vmin(vec3 a, vec3 b) { return min(a, b); }

#ifdef VKRT_AABB_INTERSECTION
bool vkrtIntersectAabb(uint geometryIndex, uint primitiveIndex, vec3 origin, vec3 direction,
                       float tMin, float tMax, vec3 boxMin, vec3 boxMax, out float t,
                       out vec2 attributes) {
    t = tMin;
    attributes = vec2(0.0);
    return true;
}
#endif

void main() {
    uint i = gl_GlobalInvocationID.x;
    Ray r = Ray(spheres[i].xyz, motions[i].xyz);
    VkrtHit h = vkrtTraceClosest(r.o, 0.0, r.d, INF);
    bool blocked = vkrtTraceAny(r.o, 0.0, r.d, PI);
    Hit mine = trace_ray(r);
    scene_info.results[i] = vec4(h.t + mine.t + float(kd_nodes[0] + primitive_count() + NO_NODE +
                                 KD_LEAF + DEAD + STACK_SIZE + INTERSECTOR + MAX_TRAVERSAL_STEPS),
                                 hit_sphere(r) || blocked ? 1.0 : 0.0,
                                 is_finite(tri_verts[i]) ? 1.0 : 0.0,
                                 float(FP64_FALLBACK + GEOM_BINDING + TEXEL_NODES) +
                                 vmin(r.o, r.d).x + float(INTERSECT_WATERTIGHT));
}
"#;

/// The library's modes (`-D` sets) a renderer compiles with.
const MODES: &[&[&str]] = &[
    &[],
    &["VKRT_TEXEL_BUFFERS"],
    &["VKRT_DEVICE_ADDRESS"],
    &["VKRT_EXACT"],
    &["VKRT_EXACT", "VKRT_TEXEL_BUFFERS"],
    &["VKRT_EXACT", "VKRT_DEVICE_ADDRESS"],
    &["VKRT_MOLLER_TRUMBORE"],
    &["VKRT_AABB_INTERSECTION"],
    &["VKRT_RAY_QUERY"],
    &["VKRT_WALK=VKRT_WALK_KDTREE"],
    &["VKRT_WALK=VKRT_WALK_BVH_WIDE"],
    &["VKRT_MAX_TRAVERSAL_STEPS=1000u"],
];

/// Compiles `source` with glslc (the renderer's own compiler) and `defines`; the SPIR-V.
fn compile(source: &str, defines: &[&str]) -> Result<Vec<u32>, String> {
    common::compile_glsl(source, defines)
}

/// The `OpCapability` operands of a SPIR-V module.
fn capabilities(spirv: &[u32]) -> Vec<u32> {
    const OP_CAPABILITY: u32 = 17;
    let mut caps = Vec::new();
    let mut at = 5; // past the header
    while at < spirv.len() {
        let (count, op) = ((spirv[at] >> 16) as usize, spirv[at] & 0xffff);
        if count == 0 {
            break;
        }
        if op == OP_CAPABILITY {
            caps.push(spirv[at + 1]);
        }
        at += count;
    }
    caps
}

// SPIR-V capability numbers.
const SHADER: u32 = 1;
const FLOAT64: u32 = 10;
const INT64: u32 = 11;
const SAMPLED_BUFFER: u32 = 46;
const RAY_QUERY_KHR: u32 = 4472;
const PHYSICAL_STORAGE_BUFFER_ADDRESSES: u32 = 5347;

#[test]
fn a_renderer_shader_declaring_common_names_compiles_in_every_mode() {
    let mut failures = Vec::new();
    for defines in MODES {
        if let Err(e) = compile(RENDERER_SHADER, defines) {
            failures.push(format!("{defines:?}:\n{e}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn the_same_names_clash_without_the_library_s_prefix() {
    // The check above can fail: a shader declaring a name twice is refused by glslc.
    let twice = RENDERER_SHADER.replace(
        "const float PI = 3.14159265;",
        "const float PI = 3.14159265;\nconst float PI = 3.0;",
    );
    assert!(compile(&twice, &[]).is_err());
}

/// A renderer's `GL_EXT_ray_query` shader through `vkrt/ext_ray_query.glsl`, declaring
/// the common names after the include.
const EXT_RAY_QUERY_SHADER: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"

#define NO_HIT 0xfffffffeu
#define DEAD 9u
const float FLT_MIN = 1.0e-30;
const float PI = 3.14159265;
const float INF = 1.0 / 0.0;
struct Ray { vec3 o; vec3 d; };
struct Hit { float t; uint id; };
struct Query { uint q; };
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1) buffer Spheres { vec4 spheres[]; };
layout(set = 0, binding = 2) buffer Motions { vec4 motions[]; };
layout(set = 0, binding = 3) buffer Out { vec4 results[]; } scene_info;
uint stack[4];
float dot3(vec3 a, vec3 b) { return dot(a, b); }
bool is_nan(float x) { return x != x; }
Hit trace_ray(Ray r) { return Hit(INF, NO_HIT); }

void main() {
    uint i = gl_GlobalInvocationID.x;
    Ray r = Ray(spheres[i].xyz, motions[i].xyz);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, 0xFF, r.o, 0.0, r.d, INF);
    while (rayQueryProceedEXT(q)) {
        rayQueryConfirmIntersectionEXT(q);
    }
    stack[0] = DEAD;
    float t = rayQueryGetIntersectionTEXT(q, true);
    scene_info.results[i] = vec4(t + trace_ray(r).t + PI + FLT_MIN + float(stack[0]),
                                 dot3(r.o, r.d), is_nan(t) ? 1.0 : 0.0, 0.0);
}
"#;

#[test]
fn a_ray_query_shader_declaring_common_names_needs_no_ray_query_capability() {
    let mut got = capabilities(&compile(EXT_RAY_QUERY_SHADER, &[]).unwrap());
    got.sort_unstable();
    // docs/ray-queries.md: bufferDeviceAddress and shaderInt64, a texel buffer for the
    // structure, and no RayQueryKHR.
    let mut want = vec![
        SHADER,
        INT64,
        SAMPLED_BUFFER,
        PHYSICAL_STORAGE_BUFFER_ADDRESSES,
    ];
    want.sort_unstable();
    assert_eq!(got, want);
    // The same source on the driver's own ray query.
    let native = capabilities(&compile(EXT_RAY_QUERY_SHADER, &["VKRT_NATIVE_RAY_QUERY"]).unwrap());
    assert!(native.contains(&RAY_QUERY_KHR), "{native:?}");
}

#[test]
fn each_mode_needs_the_capabilities_its_documentation_names_and_no_more() {
    // `vkrt/ray_query.glsl`'s header and docs/embedding.md list these per define, with the
    // device features they ask for (Int64: shaderInt64; Float64: shaderFloat64;
    // PhysicalStorageBufferAddresses: bufferDeviceAddress; RayQueryKHR: VK_KHR_ray_query;
    // SampledBuffer: core).
    let cases: &[(&[&str], &[u32])] = &[
        (&[], &[SHADER]),
        (&["VKRT_AABB_INTERSECTION"], &[SHADER]),
        (&["VKRT_TEXEL_BUFFERS"], &[SHADER, SAMPLED_BUFFER]),
        (
            &["VKRT_DEVICE_ADDRESS"],
            &[SHADER, INT64, PHYSICAL_STORAGE_BUFFER_ADDRESSES],
        ),
        (&["VKRT_EXACT"], &[SHADER, FLOAT64, INT64]),
        (&["VKRT_RAY_QUERY"], &[SHADER, INT64, RAY_QUERY_KHR]),
    ];
    for (defines, want) in cases {
        let mut got = capabilities(&compile(RENDERER_SHADER, defines).unwrap());
        got.sort_unstable();
        let mut want = want.to_vec();
        want.sort_unstable();
        assert_eq!(got, want, "capabilities of {defines:?}");
    }
}
