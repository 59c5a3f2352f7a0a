//! The conformance suite's ray-query families (`dEQP-VK.ray_query.*`), written here as
//! `GL_EXT_ray_query` compute shaders run through `vkrt shader-check`'s machinery: each
//! committed getter per intersection type, the candidate set, ray flags over triangles and
//! boxes, cull masks, terminate on first hit, two queries in one invocation with one passed
//! to a function, and watertightness at shared edges. Where the driver has ray query (Mesa
//! 25.0.7 and 26.1.6 lavapipe) vkrt and the driver agree on every ray
//! (`shader_check::records_agree`: equal words, or floats within 2^-16 of the larger of 1
//! and their magnitudes); without it
//! (Debian 12's Mesa 22.3) vkrt alone agrees with the answers the 25.0.7 driver recorded
//! (`tests/data/ray_query/*.results`; `VKRT_RECORD_RAY_QUERY_ANSWERS=1` on a driver with ray
//! query writes them again). Where a driver and the specification disagree, the
//! specification wins: the families avoid what it leaves open (which of two hits at the
//! same t, the order of candidates). Each family also runs without the include, its
//! SPIR-V for the driver rewritten by the SPIR-V pass (`vkrt::spirv`): the same answers.
//! Beside the families, the shapes real shaders take: a query initialized in a helper, a
//! many-sample shader on a driver with a loop budget, and a 64-sample path tracer over an
//! image that reads its meshes at device addresses.

mod common;

use std::path::{Path, PathBuf};

use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::shader_library;
use vkrt::accel::walk::Traversal;
use vkrt::scene::Scene;
use vkrt::shader_check::levels::SceneLevels;
use vkrt::shader_check::{
    compile_shader, lower_shader, lower_shader_with, mismatches, run_driver, run_vkrt,
    run_vkrt_walking, scene_levels, Through,
};
use vkrt::spirv::LowerOptions;
use vkrt::trace::Ray;

const RAYS: usize = 384;

/// Spheres of the scene (the last instance's box primitives), in the shaders and the TOML.
const SPHERES: [[f32; 4]; 3] = [
    [0.0, 0.0, 3.0, 0.6],
    [2.5, 2.5, 0.0, 0.8],
    [-2.5, -2.0, 1.0, 0.5],
];

/// Every instance key and flag: five mesh entries over three meshes, then the spheres.
fn scene_toml() -> String {
    let mut s = String::new();
    let entries = [
        ("ball.obj", "translate = [0.0, 0.0, 0.0]"),
        (
            "ball.obj",
            "translate = [3.0, 0.0, 0.0]\nflags = [\"flip-facing\"]\ncustom_index = 77\nsbt_offset = 5\nmask = 2",
        ),
        (
            "plate.obj",
            "translate = [0.0, 3.0, 0.0]\nrotate = [30, 0, 0]\nopaque = false\nflags = [\"cull-disable\"]\nmask = 4",
        ),
        (
            "ball.obj",
            "translate = [0.0, -3.0, 0.0]\nscale = 1.5\nflags = [\"force-no-opaque\"]\nmask = 8",
        ),
        (
            "plate.obj",
            "translate = [-3.0, 0.0, 0.0]\nrotate = [0, 60, 0]\nopaque = false\nflags = [\"force-opaque\"]\nmask = 16\ncustom_index = 4000",
        ),
    ];
    for (file, keys) in entries {
        s += &format!("[[meshes]]\npath = \"{file}\"\n{keys}\n\n");
    }
    for [x, y, z, r] in SPHERES {
        s += &format!("[[spheres]]\ncenter = [{x:?}, {y:?}, {z:?}]\nradius = {r:?}\n\n");
    }
    s
}

/// An icosphere (closed: rays from outside meet front faces first) and a square plate.
fn write_meshes(dir: &Path) {
    let ball = vkrt::scene::gen::icosphere(2).unwrap();
    let mut obj = String::new();
    for p in ball.positions.iter() {
        obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in ball.indices.iter() {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(dir.join("ball.obj"), obj).unwrap();
    std::fs::write(
        dir.join("plate.obj"),
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n",
    )
    .unwrap();
}

/// A grid of 8 x 8 squares (two triangles each) in z = 0, for watertightness.
fn write_grid(dir: &Path) {
    let mut obj = String::new();
    for y in 0..=8 {
        for x in 0..=8 {
            obj += &format!("v {} {} 0\n", x as f32 * 0.25 - 1.0, y as f32 * 0.25 - 1.0);
        }
    }
    for y in 0..8 {
        for x in 0..8 {
            let v = |dx: u32, dy: u32| (y + dy) * 9 + x + dx + 1;
            obj += &format!("f {} {} {}\n", v(0, 0), v(1, 0), v(1, 1));
            obj += &format!("f {} {} {}\n", v(0, 0), v(1, 1), v(0, 1));
        }
    }
    std::fs::write(dir.join("grid.obj"), obj).unwrap();
    std::fs::write(dir.join("grid.toml"), "[[meshes]]\npath = \"grid.obj\"\n").unwrap();
}

/// Rays from a sphere of radius 8 at points near the scene's instances and spheres; some
/// bounded, some starting at tMin > 0.
fn scene_rays() -> Vec<Ray> {
    let mut rng = common::Rng(54);
    let targets = [
        [0.0, 0.0, 0.0],
        [3.0, 0.0, 0.0],
        [0.0, 3.0, 0.0],
        [0.0, -3.0, 0.0],
        [-3.0, 0.0, 0.0],
        [0.0, 0.0, 3.0],
        [2.5, 2.5, 0.0],
        [-2.5, -2.0, 1.0],
    ];
    (0..RAYS)
        .map(|i| {
            let c = glam::Vec3::from_array(targets[i % targets.len()]);
            let dir = glam::Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0
                - glam::Vec3::ONE;
            let o = dir.normalize_or(glam::Vec3::X) * 8.0;
            let aim = c
                + (glam::Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())
                    - glam::Vec3::splat(0.5))
                    * 1.6;
            match i % 5 {
                3 => Ray::new(o, aim - o, 0.0, 0.9),
                4 => Ray::new(o, aim - o, 0.4, f32::INFINITY),
                _ => Ray::new(o, aim - o, 0.0, f32::INFINITY),
            }
        })
        .collect()
}

/// Straight down onto the grid through its vertices and the midpoints of its edges (shared
/// by two triangles, or by up to six at a vertex): every ray must hit.
fn grid_rays() -> Vec<Ray> {
    let mut rays = Vec::new();
    for y in 0..=16 {
        for x in 0..=16 {
            let (px, py) = (x as f32 * 0.125 - 1.0, y as f32 * 0.125 - 1.0);
            if px.abs() < 1.0 && py.abs() < 1.0 {
                rays.push(Ray::new(
                    glam::Vec3::new(px, py, 2.0),
                    glam::Vec3::new(0.0, 0.0, -1.0),
                    0.0,
                    f32::INFINITY,
                ));
            }
        }
    }
    rays
}

/// The shaders' common part: the interface, the spheres and the candidate decisions.
fn prelude() -> String {
    let spheres: Vec<String> = SPHERES
        .iter()
        .map(|[x, y, z, r]| format!("vec4({x:?}, {y:?}, {z:?}, {r:?})"))
        .collect();
    format!(
        r#"#version 460
#extension GL_EXT_ray_query : require
#extension GL_EXT_ray_flags_primitive_culling : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays {{ vec4 rays[]; }};
layout(set = 0, binding = 2, std430) writeonly buffer Results {{ uvec4 results[]; }};
layout(push_constant) uniform Count {{ uint rayCount; }};

const vec4 SPHERES[{n}] = vec4[]({list});

// A box candidate's sphere, intersected in object space (the identity here): generated
// where the ray meets it.
void intersectSphere(rayQueryEXT q) {{
    vec4 s = SPHERES[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
    vec3 o = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - s.xyz;
    vec3 d = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
    float a = dot(d, d);
    float b = dot(o, d);
    float c = dot(o, o) - s.w * s.w;
    float disc = b * b - a * c;
    if (disc >= 0.0) {{
        float t0 = (-b - sqrt(disc)) / a;
        float t1 = (-b + sqrt(disc)) / a;
        rayQueryGenerateIntersectionEXT(q, t0 >= rayQueryGetRayTMinEXT(q) ? t0 : t1);
    }}
}}

// Non-opaque triangles confirmed, boxes intersected: the closest hit of the whole scene.
bool advance(rayQueryEXT q) {{
    bool more = rayQueryProceedEXT(q);
    if (more) {{
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {{
            rayQueryConfirmIntersectionEXT(q);
        }} else {{
            intersectSphere(q);
        }}
    }}
    return more;
}}

bool committed(rayQueryEXT q) {{
    return rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT;
}}

bool triangle(rayQueryEXT q) {{
    return rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionTriangleEXT;
}}

// Small integers (below 2^29) are compared exactly. Front face and barycentrics are defined
// for triangles only: a generated hit's are whatever the driver left there.
uint packed(rayQueryEXT q) {{
    return rayQueryGetIntersectionTypeEXT(q, true)
        | ((triangle(q) && rayQueryGetIntersectionFrontFaceEXT(q, true) ? 1u : 0u) << 2u)
        | (uint(rayQueryGetIntersectionInstanceIdEXT(q, true)) << 3u)
        | (uint(rayQueryGetIntersectionGeometryIndexEXT(q, true)) << 9u);
}}
"#,
        n = SPHERES.len(),
        list = spheres.join(", ")
    )
}

/// `main`'s start: ray `i` read as (o, tmin, d, tmax).
const MAIN: &str = r#"
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) {
        return;
    }
    vec3 o = rays[2 * i].xyz;
    float tmin = rays[2 * i].w;
    vec3 d = rays[2 * i + 1].xyz;
    float tmax = rays[2 * i + 1].w;
"#;

/// A closest-hit query with every candidate decided.
const CLOSEST: &str = r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, 0xFF, o, tmin, d, tmax);
    while (advance(q)) {
    }
    if (!committed(q)) {
        results[i] = uvec4(0xffffffffu);
        return;
    }
"#;

/// The families: name, scene (`scene` or `grid`), the body of `main`.
fn families() -> Vec<(&'static str, &'static str, String)> {
    let closest = |tail: &str| format!("{CLOSEST}{tail}");
    vec![
        (
            "committed_t_barycentrics_type_facing",
            "scene",
            closest(
                "    vec2 b = triangle(q) ? rayQueryGetIntersectionBarycentricsEXT(q, true) : vec2(0.0);\n    results[i] = uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)), floatBitsToUint(b.x), floatBitsToUint(b.y), packed(q));\n",
            ),
        ),
        (
            "committed_indices",
            "scene",
            closest(
                "    results[i] = uvec4(rayQueryGetIntersectionPrimitiveIndexEXT(q, true), rayQueryGetIntersectionInstanceCustomIndexEXT(q, true), rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(q, true), packed(q));\n",
            ),
        ),
        (
            "committed_object_ray",
            "scene",
            closest(
                "    vec3 oo = rayQueryGetIntersectionObjectRayOriginEXT(q, true);\n    vec3 od = rayQueryGetIntersectionObjectRayDirectionEXT(q, true);\n    results[i] = uvec4(floatBitsToUint(oo.x), floatBitsToUint(oo.y), floatBitsToUint(oo.z), floatBitsToUint(od.x + od.y + od.z));\n",
            ),
        ),
        (
            "committed_transforms",
            "scene",
            closest(
                "    mat4x3 otw = rayQueryGetIntersectionObjectToWorldEXT(q, true);\n    mat4x3 wto = rayQueryGetIntersectionWorldToObjectEXT(q, true);\n    results[i] = uvec4(floatBitsToUint(otw[3].x), floatBitsToUint(otw[0].y + otw[1].z), floatBitsToUint(wto[3].y), floatBitsToUint(wto[2].x + wto[0].z));\n",
            ),
        ),
        (
            "ray_getters",
            "scene",
            r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsCullBackFacingTrianglesEXT, 0x7F, o, tmin, d, tmax);
    vec3 wo = rayQueryGetWorldRayOriginEXT(q);
    vec3 wd = rayQueryGetWorldRayDirectionEXT(q);
    results[i] = uvec4(floatBitsToUint(wo.x + wd.y), floatBitsToUint(wo.z), floatBitsToUint(rayQueryGetRayTMinEXT(q)), rayQueryGetRayFlagsEXT(q));
"#
            .into(),
        ),
        (
            "candidate_set",
            "scene",
            r#"
    // Opaque hits culled, nothing committed: every non-opaque triangle on the ray is a
    // candidate, whatever the walk's order (with opaque hits committed on the way, which
    // candidates lie beyond them when met is the walk's choice). Boxes are left out: a
    // box candidate may be reported conservatively.
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsCullOpaqueEXT, 0xFF, o, tmin, d, tmax);
    uint triangles = 0u;
    uint front = 0u;
    uint ids = 0u;
    float nearest = 1.0e30;
    while (rayQueryProceedEXT(q)) {
        uint id = uint(rayQueryGetIntersectionInstanceIdEXT(q, false)) * 4096u + uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, false));
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {
            triangles++;
            front += rayQueryGetIntersectionFrontFaceEXT(q, false) ? 1u : 0u;
            ids = (ids + id) & 0x3fffffu;
            nearest = min(nearest, rayQueryGetIntersectionTEXT(q, false));
        }
    }
    results[i] = uvec4(triangles, front, ids, floatBitsToUint(nearest));
"#
            .into(),
        ),
        (
            "ray_flags",
            "scene",
            r#"
    const uint FLAGS[12] = uint[](
        gl_RayFlagsNoneEXT, gl_RayFlagsOpaqueEXT, gl_RayFlagsNoOpaqueEXT,
        gl_RayFlagsCullBackFacingTrianglesEXT, gl_RayFlagsCullFrontFacingTrianglesEXT,
        gl_RayFlagsCullOpaqueEXT, gl_RayFlagsCullNoOpaqueEXT, gl_RayFlagsSkipTrianglesEXT,
        gl_RayFlagsSkipAABBEXT, gl_RayFlagsNoOpaqueEXT | gl_RayFlagsCullBackFacingTrianglesEXT,
        gl_RayFlagsOpaqueEXT | gl_RayFlagsCullFrontFacingTrianglesEXT,
        gl_RayFlagsCullOpaqueEXT | gl_RayFlagsSkipAABBEXT);
    uint flags = FLAGS[i % 12u];
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, flags, 0xFF, o, tmin, d, tmax);
    while (advance(q)) {
    }
    results[i] = committed(q)
        ? uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)), packed(q), rayQueryGetIntersectionPrimitiveIndexEXT(q, true), flags)
        : uvec4(0xffffffffu, 0u, 0u, flags);
"#
            .into(),
        ),
        (
            "cull_mask",
            "scene",
            r#"
    uint mask = (i * 37u) & 0xFFu;
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, mask, o, tmin, d, tmax);
    while (advance(q)) {
    }
    results[i] = committed(q)
        ? uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)), packed(q), rayQueryGetIntersectionPrimitiveIndexEXT(q, true), mask)
        : uvec4(0xffffffffu, 0u, 0u, mask);
"#
            .into(),
        ),
        (
            "terminate_on_first_hit",
            "scene",
            r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsTerminateOnFirstHitEXT, 0xFF, o, tmin, d, tmax);
    while (advance(q)) {
    }
    // Which hit ends the query is the walk's choice; that one does is not.
    rayQueryEXT r;
    rayQueryInitializeEXT(r, scene, gl_RayFlagsNoneEXT, 0xFF, o, tmin, d, tmax);
    while (rayQueryProceedEXT(r)) {
        rayQueryTerminateEXT(r);
    }
    results[i] = uvec4(committed(q) ? 1u : 0u, rayQueryProceedEXT(r) ? 1u : 0u, 0u, 0u);
"#
            .into(),
        ),
        (
            "two_queries_one_passed_to_a_function",
            "scene",
            r#"
    rayQueryEXT a;
    rayQueryEXT b;
    rayQueryInitializeEXT(a, scene, gl_RayFlagsNoneEXT, 0xFF, o, tmin, d, tmax);
    rayQueryInitializeEXT(b, scene, gl_RayFlagsNoneEXT, 0x03, o, tmin, d, tmax);
    bool more_a = true;
    bool more_b = true;
    while (more_a || more_b) {
        if (more_a) {
            more_a = advance(a);
        }
        if (more_b) {
            more_b = advance(b);
        }
    }
    results[i] = uvec4(committed(a) ? floatBitsToUint(rayQueryGetIntersectionTEXT(a, true)) : 0xffffffffu,
                       committed(a) ? packed(a) : 0u,
                       committed(b) ? floatBitsToUint(rayQueryGetIntersectionTEXT(b, true)) : 0xffffffffu,
                       committed(b) ? packed(b) : 0u);
"#
            .into(),
        ),
        (
            "watertight_shared_edges",
            "grid",
            r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, 0xFF, o, tmin, d, tmax);
    while (advance(q)) {
    }
    // Which of the triangles sharing the edge answers is open; that one does is not.
    results[i] = uvec4(committed(q) ? 1u : 0u, committed(q) ? floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)) : 0u, 0u, 0u);
"#
            .into(),
        ),
    ]
}

/// Fails, naming how many rays and the first three, where the records of `a` and `b`
/// differ (`shader_check::records_agree`).
fn assert_agree(a: &[[u32; 4]], b: &[[u32; 4]], what: std::fmt::Arguments) {
    let differ = mismatches(a, b);
    assert!(
        differ.is_empty(),
        "{what}: {} rays, first {:x?}",
        differ.len(),
        &differ[..differ.len().min(3)]
    );
}

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/ray_query")
}

fn lbvh(walk: Traversal) -> AccelChoice {
    AccelChoice::new(AccelKind::Lbvh, walk)
}

fn read_results(path: &Path) -> Option<Vec<[u32; 4]>> {
    let bytes = std::fs::read(path).ok()?;
    Some(bytemuck::pod_collect_to_vec::<u8, [u32; 4]>(&bytes))
}

#[test]
fn ray_query_families_agree_with_the_driver_s_answers() {
    let Some(ctx) = common::context() else { return };
    let dir = std::env::temp_dir().join(format!("vkrt-rq-families-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_meshes(&dir);
    write_grid(&dir);
    std::fs::write(dir.join("scene.toml"), scene_toml()).unwrap();
    let include = dir.join("include");
    shader_library::write_to(&include).unwrap();
    let native = vkrt::gpu::require_ray_query(&ctx).is_ok();
    let record = native && std::env::var_os("VKRT_RECORD_RAY_QUERY_ANSWERS").is_some();
    // Both variants are compiled everywhere: the driver's is also what the SPIR-V pass
    // lowers.
    let through = Through::Both;
    let scenes = [("scene", scene_rays()), ("grid", grid_rays())];
    let mut compared = 0;
    for (name, scene_name, body) in families() {
        let (_, rays) = scenes.iter().find(|(s, _)| *s == scene_name).unwrap();
        let scene = Scene::load(&dir.join(format!("{scene_name}.toml")))
            .unwrap()
            .scene;
        let levels = scene_levels(&scene);
        let source = format!("{}{MAIN}{body}}}\n", prelude());
        let shader = dir.join(format!("{name}.comp"));
        let compiled = compile_shader(&shader, &source, &include, through)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!compiled.inserted_include, "{name}");
        let (spirv, iface) = compiled.vkrt.as_ref().unwrap();
        let vkrt = run_vkrt(&ctx, &levels, lbvh(Traversal::Stack), (spirv, iface), rays)
            .unwrap()
            .results;
        // The 4-wide walk of the same bottom levels: the same answers, bit for bit.
        let wide = run_vkrt(&ctx, &levels, lbvh(Traversal::Wide), (spirv, iface), rays)
            .unwrap()
            .results;
        let differ: Vec<usize> = (0..vkrt.len()).filter(|&i| vkrt[i] != wide[i]).collect();
        assert!(
            differ.is_empty(),
            "{name}: {} rays differ between the binary and the 4-wide walk, first {:?}",
            differ.len(),
            &differ[..differ.len().min(3)]
        );
        // The other loop shape (the loop-budget walk where the device has no budget, the
        // nested one where it has): the same answers, binary and 4-wide, through the include
        // and through the pass.
        let budget_walk = ctx.info().loop_budget.is_some();
        for walk in [Traversal::Stack, Traversal::Wide] {
            let other = run_vkrt_walking(
                &ctx,
                &levels,
                lbvh(walk),
                (spirv, iface),
                rays,
                !budget_walk,
            )
            .unwrap()
            .results;
            assert_agree(
                &vkrt,
                &other,
                format_args!(
                    "{name}: rays differ between the nested and the loop-budget walk ({walk:?})"
                ),
            );
        }
        let recorded_path = data_dir().join(format!("{name}.results"));
        // The same shader without the include, its SPIR-V lowered by the pass: the same
        // walk, so the same answers, with either loop the pass links.
        let (native_words, _) = compiled.native.as_ref().unwrap();
        for loop_budget in [false, true] {
            let options = LowerOptions {
                loop_budget,
                ..LowerOptions::default()
            };
            let (lowered, lowered_iface) = lower_shader_with(&shader, native_words, &options)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            let passed = run_vkrt(
                &ctx,
                &levels,
                lbvh(Traversal::Stack),
                (&lowered, &lowered_iface),
                rays,
            )
            .unwrap()
            .results;
            assert_agree(
                &vkrt,
                &passed,
                format_args!(
                    "{name}: rays differ between the include and the SPIR-V pass \
                 (loop_budget: {loop_budget})"
                ),
            );
        }
        if let Some((spirv, iface)) = compiled.native.as_ref().filter(|_| native) {
            let driver = run_driver(&ctx, &levels, (spirv, iface), rays)
                .unwrap()
                .results;
            assert_agree(
                &driver,
                &vkrt,
                format_args!("{name}: rays differ from the driver's"),
            );
            if record {
                std::fs::create_dir_all(data_dir()).unwrap();
                std::fs::write(&recorded_path, bytemuck::cast_slice(&driver)).unwrap();
            }
        }
        let recorded = read_results(&recorded_path).unwrap_or_else(|| {
            panic!("{name}: no recorded answers at {}", recorded_path.display())
        });
        assert_agree(
            &recorded,
            &vkrt,
            format_args!("{name}: rays differ from the answers Mesa 25.0.7's ray query recorded"),
        );
        // Each family must say something: beyond its most common answer (a miss, mostly),
        // a tenth of its rays answer otherwise.
        let mut counts = std::collections::HashMap::new();
        for r in &vkrt {
            *counts.entry(*r).or_insert(0usize) += 1;
        }
        let common = counts.values().copied().max().unwrap_or(0);
        assert!(
            rays.len() - common > rays.len() / 10 || name == "watertight_shared_edges",
            "{name}: {common} of {} rays give the same answer",
            rays.len()
        );
        if name == "watertight_shared_edges" {
            assert!(
                vkrt.iter().all(|r| r[0] == 1),
                "{name}: a ray slipped through"
            );
        }
        compared += rays.len();
    }
    assert!(compared > 3000);
    let _ = std::fs::remove_dir_all(&dir);
    common::assert_silent(&ctx);
}

/// WGSL, compiled to SPIR-V by naga (wgpu's shader compiler), lowered by the SPIR-V pass:
/// the family `committed_indices` written in WGSL gives the answers Mesa 25.0.7's ray query
/// recorded for the GLSL, on every driver, and the driver's own answers where it has ray
/// query.
#[test]
fn wgsl_through_naga_and_the_pass_gives_the_recorded_answers() {
    let Some(ctx) = common::context() else { return };
    let dir = std::env::temp_dir().join(format!("vkrt-rq-wgsl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_meshes(&dir);
    std::fs::write(dir.join("scene.toml"), scene_toml()).unwrap();
    let scene = Scene::load(&dir.join("scene.toml")).unwrap().scene;
    let levels = scene_levels(&scene);
    let rays = scene_rays();
    let source = std::fs::read_to_string(data_dir().join("committed_indices.wgsl")).unwrap();
    let module = naga::front::wgsl::parse_str(&source)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .unwrap();
    let options = naga::back::spv::Options {
        lang_version: (1, 4),
        ..Default::default()
    };
    let words = naga::back::spv::write_vec(&module, &info, &options, None).unwrap();
    let shader = dir.join("committed_indices.wgsl");
    let native = vkrt::shader_check::native_shader(&shader, words).unwrap();
    let (lowered, iface) = lower_shader(&shader, &native.0).unwrap();
    // The lowered module is valid SPIR-V for Vulkan 1.2 (spirv-val, Debian's spirv-tools).
    let spv = dir.join("lowered.spv");
    std::fs::write(&spv, bytemuck::cast_slice(&lowered)).unwrap();
    let val = std::process::Command::new("spirv-val")
        .args(["--target-env", "vulkan1.2"])
        .arg(&spv)
        .output()
        .expect("spirv-val (./x setup installs spirv-tools)");
    assert!(
        val.status.success(),
        "spirv-val: {}",
        String::from_utf8_lossy(&val.stderr)
    );
    let got = run_vkrt(
        &ctx,
        &levels,
        lbvh(Traversal::Stack),
        (&lowered, &iface),
        &rays,
    )
    .unwrap()
    .results;
    let recorded = read_results(&data_dir().join("committed_indices.results")).unwrap();
    let differ = mismatches(&recorded, &got);
    assert!(
        differ.is_empty(),
        "{} rays differ from the recorded answers, first {:x?}",
        differ.len(),
        &differ[..differ.len().min(3)]
    );
    if vkrt::gpu::require_ray_query(&ctx).is_ok() {
        let driver = run_driver(&ctx, &levels, (&native.0, &native.1), &rays)
            .unwrap()
            .results;
        let differ = mismatches(&driver, &got);
        assert!(
            differ.is_empty(),
            "{} rays differ from the driver's",
            differ.len()
        );
    }
    let hits = got.iter().filter(|r| r[0] != u32::MAX).count();
    assert!(
        hits > rays.len() / 10 && hits < rays.len(),
        "{hits} of {} rays hit",
        rays.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The square of the small scenes below: two triangles in the plane z = 0, of half-size
/// `h`.
fn square_obj(h: f32) -> String {
    format!("v -{h} -{h} 0\nv {h} -{h} 0\nv {h} {h} 0\nv -{h} {h} 0\nf 1 2 3\nf 1 3 4\n")
}

/// A scratch directory named after `name` holding the square (`square.obj`, half-size `h`)
/// and `scene` as `scene.toml`, with vkrt's include files under `include/`; the scene's
/// levels.
fn small_scene(name: &str, h: f32, scene: &str) -> (PathBuf, SceneLevels) {
    let dir = std::env::temp_dir().join(format!("vkrt-rq-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("square.obj"), square_obj(h)).unwrap();
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    shader_library::write_to(&dir.join("include")).unwrap();
    let scene = Scene::load(&dir.join("scene.toml")).unwrap().scene;
    (dir, scene_levels(&scene))
}

/// The start of a query shader in `vkrt shader-check`'s interface; `INIT(q, flags)` starts
/// query `q` on ray `i`.
const INTERFACE: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; };
#define INIT(q, flags) rayQueryInitializeEXT(q, scene, flags, 0xFF, rays[2 * i].xyz, rays[2 * i].w, rays[2 * i + 1].xyz, rays[2 * i + 1].w)
"#;

/// `native` (SPIR-V for the driver's query) lowered by the pass and run through vkrt's
/// levels (binary LBVH walk): what it wrote.
fn through_pass(
    ctx: &vkrt::gpu::Context,
    levels: &SceneLevels,
    path: &Path,
    native: &[u32],
    rays: &[Ray],
) -> Vec<[u32; 4]> {
    let (lowered, iface) = lower_shader(path, native).unwrap();
    run_vkrt(
        ctx,
        levels,
        lbvh(Traversal::Stack),
        (&lowered, &iface),
        rays,
    )
    .unwrap()
    .results
}

/// Position fetch (`GL_EXT_ray_tracing_position_fetch`): a committed triangle's vertices in
/// object space, through the include and through the SPIR-V pass, equal to the mesh's own.
/// The driver's module declares `RayQueryPositionFetchKHR`, which Debian 12's glslc and
/// validation layer (1.3.239) predate: it is made from a shader that asks for the
/// object-to-world matrix (read the same way, by columns), with that one instruction
/// replaced, and runs through the pass only.
#[test]
fn position_fetch_gives_the_mesh_s_vertices_through_the_include_and_the_pass() {
    let Some(ctx) = common::context() else { return };
    // A square in its object space, two instances: one as it is, one moved and turned.
    let (dir, levels) = small_scene(
        "fetch",
        1.0,
        "[[meshes]]\npath = \"square.obj\"\n\n[[meshes]]\npath = \"square.obj\"\ntranslate = [0, 3, -1]\nrotate = [0, 0, 30]\n",
    );
    let mut rays = Vec::new();
    for j in 0..24 {
        for i in 0..16 {
            let (x, y) = (
                -1.6 + 3.2 * (i as f32 + 0.5) / 16.0,
                -1.5 + 6.0 * (j as f32 + 0.5) / 24.0,
            );
            rays.push(Ray::new(
                glam::Vec3::new(x, y, 5.0),
                -glam::Vec3::Z,
                0.0,
                f32::INFINITY,
            ));
        }
    }
    let shader = |getter: &str| {
        format!(
            r#"{INTERFACE}
void main() {{
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) return;
    rayQueryEXT q;
    INIT(q, gl_RayFlagsOpaqueEXT);
    while (rayQueryProceedEXT(q)) {{}}
    {getter}
    uint k = rayQueryGetIntersectionTypeEXT(q, true) | (uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)) << 4u);
    results[i] = uvec4(floatBitsToUint(p[0].x + 2.0 * p[0].y), floatBitsToUint(p[1].x + 2.0 * p[1].y),
                       floatBitsToUint(p[2].x + 2.0 * p[2].y + 4.0 * (p[0].z + p[1].z + p[2].z)), k);
}}
"#
        )
    };
    let include = dir.join("include");
    let path = dir.join("fetch.comp");
    let fetch = shader("vec3 p[3]; rayQueryGetIntersectionTriangleVertexPositionsEXT(q, true, p);");
    let through_include = compile_shader(&path, &fetch, &include, Through::Vkrt).unwrap();
    let (spirv, iface) = through_include.vkrt.as_ref().unwrap();
    let included = run_vkrt(&ctx, &levels, lbvh(Traversal::Stack), (spirv, iface), &rays)
        .unwrap()
        .results;

    // The driver's module: the matrix getter's instruction turned into position fetch.
    let stand_in = shader("mat4x3 p = rayQueryGetIntersectionObjectToWorldEXT(q, true);");
    let native = compile_shader(&path, &stand_in, &include, Through::Driver).unwrap();
    let words = with_position_fetch(&native.native.unwrap().0);
    let passed = through_pass(&ctx, &levels, &path, &words, &rays);
    assert_eq!(included, passed, "the include and the pass");

    // The mesh's vertices, in its object space, by primitive.
    let tri = |prim: u32| -> [[f32; 3]; 3] {
        let v = [
            [-1.0, -1.0, 0.0],
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ];
        if prim == 0 {
            [v[0], v[1], v[2]]
        } else {
            [v[0], v[2], v[3]]
        }
    };
    let mut hits = 0;
    for (r, rec) in rays.iter().zip(&passed) {
        if rec[3] & 0xf == 0 {
            assert_eq!(&rec[..3], &[0, 0, 0], "a miss has no vertices: {r:?}");
            continue;
        }
        hits += 1;
        let p = tri(rec[3] >> 4);
        let want = [
            p[0][0] + 2.0 * p[0][1],
            p[1][0] + 2.0 * p[1][1],
            p[2][0] + 2.0 * p[2][1] + 4.0 * (p[0][2] + p[1][2] + p[2][2]),
        ];
        for k in 0..3 {
            assert_eq!(f32::from_bits(rec[k]), want[k], "ray {r:?}: {rec:?}");
        }
    }
    assert!(hits > rays.len() / 4, "{hits} of {} rays hit", rays.len());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `words` with its `OpRayQueryGetIntersectionObjectToWorldKHR` turned into
/// `OpRayQueryGetIntersectionTriangleVertexPositionsKHR` (a `vec3[3]`), and the capability
/// and extension that instruction needs.
fn with_position_fetch(words: &[u32]) -> Vec<u32> {
    use rspirv::binary::Assemble;
    use rspirv::dr::{Instruction, Operand};
    use rspirv::spirv::{Capability, Op};
    let mut m = rspirv::dr::load_words(words).unwrap();
    m.capabilities.push(Instruction::new(
        Op::Capability,
        None,
        None,
        vec![Operand::Capability(Capability::RayQueryPositionFetchKHR)],
    ));
    m.extensions.push(Instruction::new(
        Op::Extension,
        None,
        None,
        vec![Operand::LiteralString(
            "SPV_KHR_ray_tracing_position_fetch".into(),
        )],
    ));
    let find = |op: Op, operands: &[Operand]| {
        m.types_global_values
            .iter()
            .find(|i| i.class.opcode == op && i.operands == operands)
            .and_then(|i| i.result_id)
            .unwrap()
    };
    let float = find(Op::TypeFloat, &[Operand::LiteralBit32(32)]);
    let uint = find(
        Op::TypeInt,
        &[Operand::LiteralBit32(32), Operand::LiteralBit32(0)],
    );
    let vec3 = find(
        Op::TypeVector,
        &[Operand::IdRef(float), Operand::LiteralBit32(3)],
    );
    let header = m.header.as_mut().unwrap();
    let (three, array, pointer) = (header.bound, header.bound + 1, header.bound + 2);
    header.bound += 3;
    m.types_global_values.push(Instruction::new(
        Op::Constant,
        Some(uint),
        Some(three),
        vec![Operand::LiteralBit32(3)],
    ));
    m.types_global_values.push(Instruction::new(
        Op::TypeArray,
        None,
        Some(array),
        vec![Operand::IdRef(vec3), Operand::IdRef(three)],
    ));
    m.types_global_values.push(Instruction::new(
        Op::TypePointer,
        None,
        Some(pointer),
        vec![
            Operand::StorageClass(rspirv::spirv::StorageClass::Function),
            Operand::IdRef(array),
        ],
    ));
    // The variable the matrix was stored in holds the array instead (its columns and the
    // array's elements are read alike: an access chain to a vec3).
    let mut stored_in = None;
    let mut replaced = 0;
    for f in m.functions.iter_mut() {
        for b in f.blocks.iter_mut() {
            for i in b.instructions.iter_mut() {
                if i.class.opcode == Op::RayQueryGetIntersectionObjectToWorldKHR {
                    *i = Instruction::new(
                        Op::RayQueryGetIntersectionTriangleVertexPositionsKHR,
                        Some(array),
                        i.result_id,
                        i.operands.clone(),
                    );
                    replaced += 1;
                }
            }
        }
    }
    assert_eq!(replaced, 1);
    let result = m
        .functions
        .iter()
        .flat_map(|f| f.blocks.iter().flat_map(|b| &b.instructions))
        .find(|i| i.class.opcode == Op::RayQueryGetIntersectionTriangleVertexPositionsKHR)
        .and_then(|i| i.result_id);
    for f in m.functions.iter() {
        for i in f.blocks.iter().flat_map(|b| &b.instructions) {
            if let (Op::Store, [Operand::IdRef(p), Operand::IdRef(v), ..]) =
                (i.class.opcode, i.operands.as_slice())
            {
                if Some(*v) == result {
                    stored_in = Some(*p);
                }
            }
        }
    }
    for f in m.functions.iter_mut() {
        for i in f.blocks.iter_mut().flat_map(|b| b.instructions.iter_mut()) {
            if i.class.opcode == Op::Variable && i.result_id == stored_in {
                i.result_type = Some(pointer);
            }
        }
    }
    assert!(stored_in.is_some());
    m.assemble()
}

/// A box is a candidate whenever the segment [tMin, committed t] meets it (the
/// specification's rule), also from an origin inside the box with an opaque triangle inside
/// it committed first: rays from inside a sphere's box onto a square within it, rays whose
/// tMin puts their start on the box's face, rays along the axes and slanted ones. Every ray
/// meets the box exactly once, through the include, the pass and the driver alike.
#[test]
fn a_box_is_a_candidate_from_an_origin_inside_it() {
    let Some(ctx) = common::context() else { return };
    let (dir, levels) = small_scene(
        "inside",
        0.5,
        "[[meshes]]\npath = \"square.obj\"\n\n[[spheres]]\ncenter = [0, 0, 0]\nradius = 1\n",
    );
    let mut rays = Vec::new();
    let mut rng = common::Rng(7);
    for k in 0..192 {
        let (x, y) = (rng.next_f32() * 0.4, rng.next_f32() * 0.4);
        rays.push(match k % 4 {
            // From inside the box, straight onto the square (axis-parallel).
            0 => Ray::new(
                glam::Vec3::new(x, y, 0.6),
                -glam::Vec3::Z,
                0.0,
                f32::INFINITY,
            ),
            // From inside, slanted onto the square.
            1 => Ray::new(
                glam::Vec3::new(x, y, 0.7),
                glam::Vec3::new(-0.2 * x, 0.3 * y, -1.0),
                0.05,
                f32::INFINITY,
            ),
            // From outside, tMin putting the start on the box's face z = 1.
            2 => Ray::new(
                glam::Vec3::new(x, y, 1.5),
                -glam::Vec3::Z,
                0.5,
                f32::INFINITY,
            ),
            // From inside, along x: the square is edge-on, the box's side ahead.
            _ => Ray::new(
                glam::Vec3::new(0.0, y, 0.3),
                glam::Vec3::X,
                0.0,
                f32::INFINITY,
            ),
        });
    }
    let source = format!(
        "{INTERFACE}{}",
        r#"
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) return;
    rayQueryEXT q;
    INIT(q, gl_RayFlagsNoneEXT);
    uint boxes = 0u;
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionAABBEXT) {
            boxes++;
        }
    }
    uint kind = rayQueryGetIntersectionTypeEXT(q, true);
    float t = kind == gl_RayQueryCommittedIntersectionNoneEXT ? 0.0 : rayQueryGetIntersectionTEXT(q, true);
    results[i] = uvec4(boxes, kind, floatBitsToUint(t), 0u);
}
"#
    );
    let path = dir.join("inside.comp");
    let compiled = compile_shader(&path, &source, &dir.join("include"), Through::Both).unwrap();
    let (spirv, iface) = compiled.vkrt.as_ref().unwrap();
    let included = run_vkrt(&ctx, &levels, lbvh(Traversal::Stack), (spirv, iface), &rays)
        .unwrap()
        .results;
    let (native, native_iface) = compiled.native.as_ref().unwrap();
    let passed = through_pass(&ctx, &levels, &path, native, &rays);
    assert_eq!(included, passed, "the include and the pass");
    for (k, (r, rec)) in rays.iter().zip(&passed).enumerate() {
        assert_eq!(rec[0], 1, "ray {k} {r:?}: the box came {} times", rec[0]);
        // Onto the square: the triangle is committed (it is opaque), at its distance.
        if k % 4 != 3 {
            assert_eq!(rec[1], 1, "ray {k} {r:?}: {rec:?}");
        }
    }
    if vkrt::gpu::require_ray_query(&ctx).is_ok() {
        let driver = run_driver(&ctx, &levels, (native, native_iface), &rays)
            .unwrap()
            .results;
        let differ = mismatches(&driver, &passed);
        assert!(
            differ.is_empty(),
            "{} rays differ from the driver's, first {:x?}",
            differ.len(),
            &differ[..differ.len().min(3)]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The conformance suite's `ray_query.advanced.using_wrapper_function`: a query *value*
/// (`OpLoad` of the query) passed to a function, which stores it in a query of its own and
/// confirms through that one; the caller's query must be the one confirmed. GLSL passes
/// queries by pointer, so the module is made from a GLSL helper taking the query, turned to
/// take it by value. Through the pass (and the driver where it has ray query), every
/// non-opaque triangle the helper confirms is the caller's committed hit.
#[test]
fn a_query_value_passed_to_a_function_is_the_same_query() {
    let Some(ctx) = common::context() else { return };
    let (dir, levels) = small_scene(
        "wrapper",
        1.0,
        "[[meshes]]\npath = \"square.obj\"\nopaque = false\n",
    );
    let rays: Vec<Ray> = (0..128)
        .map(|k| {
            let (x, y) = ((k % 16) as f32 * 0.2 - 1.55, (k / 16) as f32 * 0.4 - 1.5);
            Ray::new(
                glam::Vec3::new(x, y, 2.0),
                -glam::Vec3::Z,
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let source = format!(
        "{INTERFACE}{}",
        r#"
void confirmThrough(rayQueryEXT q) {
    rayQueryConfirmIntersectionEXT(q);
}
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) return;
    rayQueryEXT q;
    INIT(q, gl_RayFlagsNoneEXT);
    while (rayQueryProceedEXT(q)) {
        confirmThrough(q);
    }
    uint kind = rayQueryGetIntersectionTypeEXT(q, true);
    results[i] = uvec4(kind, kind == 0u ? 0u : floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                       kind == 0u ? ~0u : uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)), 0u);
}
"#
    );
    let path = dir.join("wrapper.comp");
    let compiled = compile_shader(&path, &source, &dir.join("include"), Through::Driver).unwrap();
    let (native, _) = compiled.native.as_ref().unwrap();
    let by_value = with_query_by_value(native);
    let native_iface = vkrt::shader_check::native_shader(&path, by_value.clone())
        .unwrap()
        .1;
    let passed = through_pass(&ctx, &levels, &path, &by_value, &rays);
    let mut hits = 0;
    for (r, rec) in rays.iter().zip(&passed) {
        let inside = r.origin[0].abs() < 1.0 && r.origin[1].abs() < 1.0;
        if inside {
            hits += 1;
            assert_eq!(
                rec[0], 1,
                "ray {r:?}: the helper's confirm is the caller's: {rec:?}"
            );
            assert_eq!(f32::from_bits(rec[1]), 2.0, "ray {r:?}");
        } else {
            assert_eq!(rec[0], 0, "ray {r:?}: {rec:?}");
        }
    }
    assert!(hits > 32, "{hits}");
    // Mesa's own ray query copies a query's state on a store (lavapipe lowers each query
    // variable to state of its own): through the copy, its confirm reaches nothing (Mesa
    // 25.0.7 and 26.1.6: every hit of this shader missed). The suite's expectation, which
    // vkrt meets, is the oracle here; the driver's answers are reported, not compared.
    if vkrt::gpu::require_ray_query(&ctx).is_ok() {
        let driver = run_driver(&ctx, &levels, (&by_value, &native_iface), &rays)
            .unwrap()
            .results;
        let differ = mismatches(&driver, &passed);
        eprintln!(
            "note: the driver's own ray query differs on {} of {} rays (a copied query)",
            differ.len(),
            rays.len()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `words` with its one function that takes a query by pointer (glslang's way) taking it by
/// value: the function stores the value in a query variable of its own, and each call loads
/// the caller's query and passes the value.
fn with_query_by_value(words: &[u32]) -> Vec<u32> {
    use rspirv::binary::Assemble;
    use rspirv::dr::{Instruction, Operand};
    use rspirv::spirv::{Op, StorageClass};
    let mut m = rspirv::dr::load_words(words).unwrap();
    let of = |m: &rspirv::dr::Module, op: Op| {
        m.types_global_values
            .iter()
            .find(|i| i.class.opcode == op)
            .and_then(|i| i.result_id)
            .unwrap()
    };
    let rq = of(&m, Op::TypeRayQueryKHR);
    let void = of(&m, Op::TypeVoid);
    // glslang's parameter: a pointer to the query (Private or Function storage).
    let pointers: Vec<u32> = m
        .types_global_values
        .iter()
        .filter(|i| {
            i.class.opcode == Op::TypePointer && i.operands.get(1) == Some(&Operand::IdRef(rq))
        })
        .filter_map(|i| i.result_id)
        .collect();
    let header = m.header.as_mut().unwrap();
    let (fn_type, value, pointer) = (header.bound, header.bound + 1, header.bound + 2);
    header.bound += 3;
    let mut next = header.bound;
    m.types_global_values.push(Instruction::new(
        Op::TypePointer,
        None,
        Some(pointer),
        vec![
            Operand::StorageClass(StorageClass::Function),
            Operand::IdRef(rq),
        ],
    ));
    m.types_global_values.push(Instruction::new(
        Op::TypeFunction,
        None,
        Some(fn_type),
        vec![Operand::IdRef(void), Operand::IdRef(rq)],
    ));
    let helper = m
        .functions
        .iter_mut()
        .find(|f| {
            f.parameters.len() == 1
                && f.parameters[0]
                    .result_type
                    .is_some_and(|t| pointers.contains(&t))
        })
        .unwrap();
    let helper_id = helper.def_id().unwrap();
    helper.def.as_mut().unwrap().operands[1] = Operand::IdRef(fn_type);
    let param = helper.parameters[0].result_id.unwrap();
    helper.parameters[0] = Instruction::new(Op::FunctionParameter, Some(rq), Some(value), vec![]);
    let first = &mut helper.blocks[0].instructions;
    first.insert(
        0,
        Instruction::new(
            Op::Variable,
            Some(pointer),
            Some(param),
            vec![Operand::StorageClass(StorageClass::Function)],
        ),
    );
    let after_vars = first
        .iter()
        .take_while(|i| i.class.opcode == Op::Variable)
        .count();
    first.insert(
        after_vars,
        Instruction::new(
            Op::Store,
            None,
            None,
            vec![Operand::IdRef(param), Operand::IdRef(value)],
        ),
    );
    let mut calls = 0;
    for f in m.functions.iter_mut() {
        for b in f.blocks.iter_mut() {
            let old = std::mem::take(&mut b.instructions);
            for mut i in old {
                if i.class.opcode == Op::FunctionCall && i.operands[0] == Operand::IdRef(helper_id)
                {
                    let Operand::IdRef(arg) = i.operands[1] else {
                        unreachable!()
                    };
                    let loaded = next;
                    next += 1;
                    b.instructions.push(Instruction::new(
                        Op::Load,
                        Some(rq),
                        Some(loaded),
                        vec![Operand::IdRef(arg)],
                    ));
                    i.operands[1] = Operand::IdRef(loaded);
                    calls += 1;
                }
                b.instructions.push(i);
            }
        }
    }
    assert!(calls > 0);
    m.header.as_mut().unwrap().bound = next;
    m.assemble()
}

/// A shader's own loops around many queries: 768 queries an invocation (64 samples of 12
/// jittered rays each) over the bunny. Mesa 22.3's lavapipe charges every loop of an
/// invocation against one budget of 65,535 iterations; there the nested walk spends it and
/// the shader's sample loop is cut short silently, while the loop-budget walk (the device's
/// choice) keeps all 64 samples and gives the answers Mesa 25.0.7's ray query recorded.
#[test]
fn a_many_sample_shader_keeps_its_own_loops() {
    let Some(ctx) = common::context() else { return };
    let Some(bunny) = common::bunny_path() else {
        return;
    };
    let scene = Scene::load(&bunny).unwrap().scene;
    let levels = scene_levels(&scene);
    let dir = std::env::temp_dir().join(format!("vkrt-rq-many-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let include = dir.join("include");
    shader_library::write_to(&include).unwrap();
    let shader = dir.join("many_samples.comp");
    let compiled = compile_shader(&shader, MANY_SAMPLES, &include, Through::Both).unwrap();
    let (spirv, iface) = compiled.vkrt.as_ref().unwrap();
    // 64 rays from in front of the bunny, at its body.
    let rays: Vec<Ray> = (0..64)
        .map(|k| {
            let (x, y) = ((k % 8) as f32, (k / 8) as f32);
            Ray::new(
                glam::Vec3::new(-0.045 + 0.01 * x, 0.07 + 0.01 * y, 0.4),
                glam::Vec3::new(0.0, 0.0, -1.0),
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let choice = lbvh(Traversal::Stack);
    let vkrt = run_vkrt(&ctx, &levels, choice, (spirv, iface), &rays)
        .unwrap()
        .results;
    assert!(
        vkrt.iter().all(|r| r[0] == 64),
        "the shader's sample loop was cut: {:?}",
        vkrt.iter().map(|r| r[0]).collect::<Vec<_>>()
    );
    let hits: u32 = vkrt.iter().map(|r| r[1]).sum();
    assert!(
        hits > 64 * 768 / 2,
        "{hits} hits: the rays should mostly hit"
    );
    let path = data_dir().join("many_samples_bunny.results");
    if let Some((words, native_iface)) = compiled
        .native
        .as_ref()
        .filter(|_| vkrt::gpu::require_ray_query(&ctx).is_ok())
    {
        let driver = run_driver(&ctx, &levels, (words, native_iface), &rays)
            .unwrap()
            .results;
        assert!(
            mismatches(&driver, &vkrt).is_empty(),
            "vkrt and the driver differ"
        );
        if std::env::var_os("VKRT_RECORD_RAY_QUERY_ANSWERS").is_some() {
            std::fs::write(&path, bytemuck::cast_slice(&driver)).unwrap();
        }
    }
    let recorded = read_results(&path).expect("recorded answers");
    let differ = mismatches(&recorded, &vkrt);
    assert!(
        differ.is_empty(),
        "{} rays differ from the recorded answers",
        differ.len()
    );
    if ctx.info().loop_budget.is_some() {
        // The nested walk there: its loops spend the budget and the samples are cut.
        let nested = run_vkrt_walking(&ctx, &levels, choice, (spirv, iface), &rays, false)
            .unwrap()
            .results;
        let cut = nested.iter().filter(|r| r[0] < 64).count();
        eprintln!(
            "the nested walk on a loop budget: {cut} of {} invocations lost samples",
            nested.len()
        );
        assert!(
            cut > 0,
            "the nested walk kept every sample: the budget test proves nothing"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    common::assert_silent(&ctx);
}

/// 64 samples of 12 rays, each jittered by whole multiples of 1/2048 (exact in floats), the
/// loops' trip counts unknown to the compiler. Results: samples run, hits, the sum of the
/// hit primitives' indices.
const MANY_SAMPLES: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) {
        return;
    }
    vec3 o = rays[2 * i].xyz;
    vec3 d = rays[2 * i + 1].xyz;
    uint extra = rayCount >> 31u;
    uint samples = 0u;
    uint hits = 0u;
    uint prims = 0u;
    for (uint s = 0u; s < 64u + extra; s++) {
        for (uint k = 0u; k < 12u + extra; k++) {
            vec2 j = vec2(float((s * 7u + k * 13u) % 17u) - 8.0, float((s * 5u + k * 3u) % 19u) - 9.0);
            rayQueryEXT q;
            rayQueryInitializeEXT(q, scene, gl_RayFlagsOpaqueEXT, 0xFF, o + vec3(j / 2048.0, 0.0), 0.0, d, 1e30);
            while (rayQueryProceedEXT(q)) {
            }
            if (rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT) {
                hits++;
                prims += uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true));
            }
        }
        samples++;
    }
    results[i] = uvec4(samples, hits, prims, 0u);
}
"#;

/// A path tracer as renderers write one (`examples/ray_queries/path_tracer.comp`): a
/// two-dimensional dispatch over an image, 64 samples a pixel of up to three diffuse bounces,
/// each with a shadow query toward the sun; normals from the mesh's own vertices, which it
/// reads at device addresses through the instance data (binding 3), and spheres it
/// intersects itself from the same records.
const PATH_TRACER: &str = include_str!("../examples/ray_queries/path_tracer.comp");

/// Pixels whose colours differ by more than 0.02 in any channel, and the image's mean
/// absolute difference. Paths that leave a surface a few ulp apart (each driver intersects
/// in its own order of operations) may part at a silhouette: an image, not a ray, is what
/// two drivers agree on here.
fn image_difference(a: &[[u32; 4]], b: &[[u32; 4]]) -> (usize, f64) {
    let mut off = 0;
    let mut total = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        let d = (0..3).map(|c| (f32::from_bits(x[c]) - f32::from_bits(y[c])).abs());
        let worst = d.clone().fold(0.0f32, f32::max);
        total += d.map(f64::from).sum::<f64>();
        off += usize::from(worst > 0.02 || x[3] != y[3]);
    }
    (off, total / (3 * a.len().max(1)) as f64)
}

#[test]
fn a_path_tracer_reading_instance_data_at_addresses_renders_the_driver_s_image() {
    let Some(ctx) = common::context() else { return };
    let Some(bunny) = common::bunny_path() else {
        return;
    };
    // Two bunnies (one bottom level, its arrays shared), a ground sphere and a small one.
    let toml = "[camera]\nposition = [0.0, 0.12, 0.42]\nlook_at = [0.0, 0.09, 0.0]\nfov = 40\n\n\
        [[meshes]]\npath = \"stanford-bunny.obj\"\n\n\
        [[meshes]]\npath = \"stanford-bunny.obj\"\ntranslate = [0.13, 0.0, -0.12]\nrotate = [0, 50, 0]\nscale = 0.8\n\n\
        [[spheres]]\ncenter = [0.0, -10.0, 0.0]\nradius = 10.033\n\n\
        [[spheres]]\ncenter = [-0.11, 0.07, 0.05]\nradius = 0.035\n";
    let scene = Scene::from_toml_str(toml, bunny.parent().unwrap())
        .unwrap()
        .scene;
    let levels = scene_levels(&scene);
    assert_eq!(levels.instances.len(), 3);
    // A pinhole camera's rays, row by row: 30 × 20 pixels, so that the last workgroup
    // column and row are partly outside the image.
    let (width, height) = (30u32, 20u32);
    let eye = glam::Vec3::new(0.0, 0.12, 0.42);
    let forward = (glam::Vec3::new(0.0, 0.09, 0.0) - eye).normalize();
    let right = forward.cross(glam::Vec3::Y).normalize();
    let up = right.cross(forward);
    let half = (20.0f32).to_radians().tan();
    let rays: Vec<Ray> = (0..width * height)
        .map(|k| {
            let (x, y) = ((k % width) as f32 + 0.5, (k / width) as f32 + 0.5);
            let sx = (2.0 * x / width as f32 - 1.0) * half * width as f32 / height as f32;
            let sy = (1.0 - 2.0 * y / height as f32) * half;
            Ray::new(eye, forward + sx * right + sy * up, 0.0, f32::INFINITY)
        })
        .collect();
    let dir = std::env::temp_dir().join(format!("vkrt-rq-path-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let include = dir.join("include");
    shader_library::write_to(&include).unwrap();
    let shader = dir.join("path_tracer.comp");
    let mut compiled = compile_shader(&shader, PATH_TRACER, &include, Through::Both).unwrap();
    compiled.vkrt.as_mut().unwrap().1.grid_width = Some(width);
    let native = compiled.native.as_mut().unwrap();
    native.1.grid_width = Some(width);
    let (words, mut iface) =
        lower_shader_with(&shader, &native.0, &LowerOptions::for_device(ctx.info())).unwrap();
    iface.grid_width = Some(width);
    let choice = lbvh(Traversal::Stack);
    let (spirv, vkrt_iface) = compiled.vkrt.as_ref().unwrap();
    let include_run = run_vkrt(&ctx, &levels, choice, (spirv, vkrt_iface), &rays)
        .unwrap()
        .results;
    let pass_run = run_vkrt(&ctx, &levels, choice, (&words, &iface), &rays)
        .unwrap()
        .results;
    assert!(
        include_run.iter().all(|r| r[3] == 64),
        "the shader's sample loop was cut"
    );
    let lit = include_run
        .iter()
        .filter(|r| f32::from_bits(r[0]) > 0.05)
        .count();
    assert!(lit > rays.len() / 2, "{lit} lit pixels: the image is dark");
    // Through the include and through the pass: the same walk, the same image, bit for bit.
    assert_eq!(include_run, pass_run, "the include and the pass differ");
    let path = data_dir().join("path_tracer_bunnies.results");
    if vkrt::gpu::require_ray_query(&ctx).is_ok() {
        let (native_words, native_iface) = compiled.native.as_ref().unwrap();
        let driver = run_driver(&ctx, &levels, (native_words, native_iface), &rays)
            .unwrap()
            .results;
        let (off, mean) = image_difference(&driver, &include_run);
        eprintln!(
            "vkrt ÷ driver: {off} of {} pixels differ by more than 0.02, mean |Δ| {mean:.2e}",
            rays.len()
        );
        assert!(
            off <= rays.len() / 50 && mean < 2e-3,
            "{off} pixels off, mean |Δ| {mean}: vkrt's image is not the driver's"
        );
        if std::env::var_os("VKRT_RECORD_RAY_QUERY_ANSWERS").is_some() {
            std::fs::write(&path, bytemuck::cast_slice(&driver)).unwrap();
        }
    }
    let recorded = read_results(&path).expect("recorded answers");
    let (off, mean) = image_difference(&recorded, &include_run);
    eprintln!(
        "vkrt ÷ the recorded image: {off} of {} pixels differ by more than 0.02, mean |Δ| {mean:.2e}",
        rays.len()
    );
    assert!(
        off <= rays.len() / 50 && mean < 2e-3,
        "{off} pixels off, mean |Δ| {mean}: vkrt's image is not the recorded one"
    );
    let _ = std::fs::remove_dir_all(&dir);
    common::assert_silent(&ctx);
}
