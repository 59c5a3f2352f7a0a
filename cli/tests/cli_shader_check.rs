//! `vkrt shader-check` as a renderer's engineer runs it: their own `GL_EXT_ray_query`
//! closest-hit shader over a small instanced scene (two entries of one mesh file, two
//! spheres as procedural boxes) through the driver's ray query, answers checked against
//! the scene's geometry; and every class of bad input (a shader that does not compile or
//! breaks the interface, a scene key out of range, a bad ray file) a clear error with a
//! non-zero exit and no output file.

mod common;

use std::path::{Path, PathBuf};

use common::{no_gpu_allowed, vkrt, vkrt_ok};
use glam::Vec3;
use vkrt::trace::{files, Ray};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "vkrt-cli-shader-check-{name}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// An opaque closest-hit shader as a renderer writes it: triangles committed by the query,
/// spheres intersected on their boxes and generated; per ray (t bits, instance id,
/// primitive index, committed type), a miss (0, ~0, ~0, 0).
const CLOSEST_HIT: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"

layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; };

// The scene's spheres (centre, radius), by primitive index.
const vec4 SPHERES[2] = vec4[2](vec4(-2.0, 0.0, 0.0, 0.5), vec4(2.0, 0.5, -1.0, 0.75));

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) {
        return;
    }
    vec4 o = rays[2 * i];
    vec4 d = rays[2 * i + 1];
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsOpaqueEXT, 0xff, o.xyz, o.w, d.xyz, d.w);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) != gl_RayQueryCandidateIntersectionAABBEXT) {
            continue;
        }
        vec4 sph = SPHERES[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
        vec3 oc = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - sph.xyz;
        vec3 dir = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
        float a = dot(dir, dir);
        float b = dot(oc, dir);
        float c = dot(oc, oc) - sph.w * sph.w;
        float disc = b * b - a * c;
        float best = d.w;
        if (rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT) {
            best = rayQueryGetIntersectionTEXT(q, true);
        }
        if (disc >= 0.0) {
            float t = (-b - sqrt(disc)) / a;
            if (t >= o.w && t <= best) {
                rayQueryGenerateIntersectionEXT(q, t);
            }
        }
    }
    uint kind = rayQueryGetIntersectionTypeEXT(q, true);
    if (kind == gl_RayQueryCommittedIntersectionNoneEXT) {
        results[i] = uvec4(0u, ~0u, ~0u, 0u);
    } else {
        results[i] = uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                           rayQueryGetIntersectionInstanceIdEXT(q, true),
                           rayQueryGetIntersectionPrimitiveIndexEXT(q, true), kind);
    }
}
"#;

/// A unit square in the plane z = 0, two triangles.
const SQUARE_OBJ: &str = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n";

/// Two entries of the square (the second moved up and back), then the shader's spheres.
fn scene_toml(extra_first: &str) -> String {
    format!(
        r#"[camera]
position = [0, 0, 8]
look_at = [0, 0, 0]

[[meshes]]
path = "square.obj"
{extra_first}

[[meshes]]
path = "square.obj"
translate = [0, 3, -1]

[[spheres]]
center = [-2, 0, 0]
radius = 0.5

[[spheres]]
center = [2, 0.5, -1]
radius = 0.75
"#
    )
}

/// Rays straight down -z from z = 5 on a grid over [-3, 3] x [-1.5, 4.5]: each meets at most
/// one square or sphere first.
fn grid_rays() -> Vec<Ray> {
    let mut rays = Vec::new();
    for j in 0..16 {
        for i in 0..16 {
            let x = -3.0 + 6.0 * (i as f32 + 0.5) / 16.0;
            let y = -1.5 + 6.0 * (j as f32 + 0.5) / 16.0;
            rays.push(Ray::new(Vec3::new(x, y, 5.0), -Vec3::Z, 0.0, 100.0));
        }
    }
    rays
}

struct Setup {
    dir: PathBuf,
    shader: PathBuf,
    scene: PathBuf,
    rays: PathBuf,
}

fn setup(name: &str, shader: &str, scene: &str, rays: &[Ray]) -> Setup {
    let dir = scratch(name);
    std::fs::write(dir.join("square.obj"), SQUARE_OBJ).unwrap();
    let setup = Setup {
        shader: dir.join("closest.comp"),
        scene: dir.join("scene.toml"),
        rays: dir.join("grid.rays"),
        dir,
    };
    std::fs::write(&setup.shader, shader).unwrap();
    std::fs::write(&setup.scene, scene).unwrap();
    std::fs::write(&setup.rays, files::encode_rays(rays)).unwrap();
    setup
}

fn read_records(path: &Path) -> Vec<[u32; 4]> {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes.len() % 16, 0);
    bytes
        .chunks_exact(16)
        .map(|c| {
            std::array::from_fn(|k| u32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap()))
        })
        .collect()
}

/// What the closest-hit shader must write for a grid ray at (x, y): the squares at z = 0
/// (instance 0) and z = -1 around y = 3 (instance 1), the spheres (instance 2); `None`
/// where the ray passes within `margin` of an edge (either answer is fair there).
fn expected(x: f32, y: f32, margin: f32) -> Option<(u32, f32)> {
    let near = |v: f32, edge: f32| (v - edge).abs() < margin;
    let in_square = |cx: f32, cy: f32| (x - cx).abs() <= 1.0 && (y - cy).abs() <= 1.0;
    if near(x.abs(), 1.0) || near((y - 0.0).abs(), 1.0) || near((y - 3.0).abs(), 1.0) {
        return None;
    }
    let sphere = |c: Vec3, r: f32| {
        let q = (x - c.x).powi(2) + (y - c.y).powi(2);
        if (q.sqrt() - r).abs() < margin {
            return Some(None);
        }
        (q < r * r).then(|| Some(5.0 - (c.z + (r * r - q).sqrt())))
    };
    if in_square(0.0, 0.0) {
        return Some((0, 5.0));
    }
    if in_square(0.0, 3.0) {
        return Some((1, 6.0));
    }
    for (c, r) in [
        (Vec3::new(-2.0, 0.0, 0.0), 0.5),
        (Vec3::new(2.0, 0.5, -1.0), 0.75),
    ] {
        match sphere(c, r) {
            Some(Some(t)) => return Some((2, t)),
            Some(None) => return None,
            None => {}
        }
    }
    Some((u32::MAX, 0.0))
}

/// The closest-hit shader's records for the grid rays, checked against the geometry: every
/// instance hit where a ray meets it (t, instance, primitive, committed type), misses elsewhere.
fn check_closest_hits(rays: &[Ray], records: &[[u32; 4]]) {
    assert_eq!(records.len(), rays.len());
    let mut seen = [0usize; 4];
    for (r, rec) in rays.iter().zip(records) {
        let Some((instance, t)) = expected(r.origin[0], r.origin[1], 1e-3) else {
            continue;
        };
        if instance == u32::MAX {
            assert_eq!(*rec, [0, u32::MAX, u32::MAX, 0], "ray {r:?} should miss");
            seen[3] += 1;
            continue;
        }
        assert_eq!(rec[1], instance, "ray {r:?}: {rec:?}");
        let got = f32::from_bits(rec[0]);
        assert!(
            (got - t).abs() <= 1e-4 * t,
            "ray {r:?}: t {got}, expected {t}"
        );
        // Triangles are committed by the query (type 1), spheres generated (type 2).
        assert_eq!(rec[3], if instance == 2 { 2 } else { 1 }, "ray {r:?}");
        if instance == 2 {
            // The sphere's own index as its box's primitive index.
            assert_eq!(rec[2], u32::from(r.origin[0] > 0.0));
        } else {
            assert!(rec[2] < 2, "a square has two triangles: {rec:?}");
        }
        seen[instance as usize] += 1;
    }
    assert!(
        seen.iter().all(|&n| n > 0),
        "every instance and a miss: {seen:?}"
    );
}

/// `--validate` where the Khronos layer is installed and `VKRT_VALIDATION` is not 0, as the
/// library's tests run (any message then fails the command).
fn validate() -> Vec<&'static str> {
    let layer = Path::new("/usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json");
    let off = std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0");
    if layer.exists() && !off {
        vec!["--validate"]
    } else {
        Vec::new()
    }
}

fn has_ray_query() -> bool {
    let out = vkrt(&["info", "--json"]);
    String::from_utf8_lossy(&out.stdout).contains("\"ray_query\": true")
}

#[test]
fn the_driver_runs_a_closest_hit_shader_over_the_instanced_scene() {
    if !has_ray_query() {
        eprintln!("note: the device has no ray query: the driver's path is not checked");
        return;
    }
    let rays = grid_rays();
    let st = setup("driver", CLOSEST_HIT, &scene_toml(""), &rays);
    let out_path = st.dir.join("results.bin");
    let mut args = validate();
    args.extend([
        "shader-check",
        s(&st.shader),
        s(&st.scene),
        "--rays",
        s(&st.rays),
        "--through",
        "driver",
        "-o",
        s(&out_path),
        "--json",
    ]);
    let Some(out) = vkrt_ok(&args) else {
        return;
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("validation"), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["rays"], rays.len());
    assert_eq!(v["native"], true);
    assert_eq!(v["mismatching_rays"], 0);
    assert_eq!(v["mismatches"].as_array().unwrap().len(), 0);
    assert!(v["vkrt_ms"].is_null(), "{v}");
    assert!(v["driver_ms"].as_f64().is_some_and(|ms| ms >= 0.0), "{v}");
    check_closest_hits(&rays, &read_records(&out_path));
    let _ = std::fs::remove_dir_all(&st.dir);
}

/// Runs a check through the driver that must fail: non-zero exit, `needles` in the message,
/// no output file.
fn refused(name: &str, shader: &str, scene: &str, rays: Option<&[u8]>, needles: &[&str]) {
    refused_with(name, shader, scene, rays, &["--through", "driver"], needles);
}

/// [`refused`] with `options` (the path, the structure) in place of `--through driver`.
fn refused_with(
    name: &str,
    shader: &str,
    scene: &str,
    rays: Option<&[u8]>,
    options: &[&str],
    needles: &[&str],
) {
    let st = setup(name, shader, scene, &grid_rays());
    if let Some(bytes) = rays {
        std::fs::write(&st.rays, bytes).unwrap();
    }
    let out_path = st.dir.join("results.bin");
    let mut args = vec![
        "shader-check",
        s(&st.shader),
        s(&st.scene),
        "--rays",
        s(&st.rays),
    ];
    args.extend(options);
    args.extend(["-o", s(&out_path)]);
    let out = vkrt(&args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    if no_gpu_allowed() && stderr.contains("no Vulkan") {
        return;
    }
    assert!(!out.status.success(), "{name}: should fail");
    for n in needles {
        assert!(stderr.contains(n), "{name}: expected {n:?} in: {stderr}");
    }
    assert!(!out_path.exists(), "{name}: no output on an error");
    let _ = std::fs::remove_dir_all(&st.dir);
}

#[test]
fn every_bad_input_is_a_clear_error_without_output() {
    let scene = scene_toml("");
    // A shader that does not compile: the compiler's message, naming the file and line.
    let broken = CLOSEST_HIT.replace("uint kind =", "uint kind = = ");
    refused(
        "syntax",
        &broken,
        &scene,
        None,
        &["does not compile", "closest.comp:", "error"],
    );
    // The interface broken: a missing results buffer, a 2-D workgroup, no ray count, an
    // extra binding.
    let no_results = CLOSEST_HIT
        .replace(
            "layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };",
            "",
        )
        .replace("results[i] =", "uvec4 unused =");
    refused(
        "no-results",
        &no_results,
        &scene,
        None,
        &["set 0 binding 2 is missing"],
    );
    // A two-dimensional workgroup whose push block holds no width, and a three-dimensional
    // one.
    let square = CLOSEST_HIT.replace("local_size_x = 64", "local_size_x = 8, local_size_y = 8");
    refused(
        "2d",
        &square,
        &scene,
        None,
        &["two-dimensional (8 x 8)", "uint width;"],
    );
    let cube = CLOSEST_HIT.replace(
        "local_size_x = 64",
        "local_size_x = 4, local_size_y = 4, local_size_z = 4",
    );
    refused("3d", &cube, &scene, None, &["[4, 4, 4]", "one-dimensional"]);
    let no_push = CLOSEST_HIT
        .replace(
            "layout(push_constant) uniform Count { uint rayCount; };",
            "",
        )
        .replace("i >= rayCount", "i >= 256u");
    refused("no-push", &no_push, &scene, None, &["push-constant"]);
    let extra = CLOSEST_HIT.replace(
        "layout(push_constant)",
        "layout(set = 0, binding = 4) buffer Extra { uint extra[]; };\nlayout(push_constant)",
    );
    refused(
        "extra",
        &extra,
        &scene,
        None,
        &["set 0 binding 4", "`Extra`"],
    );
    // Binding 3 holds the instance data: a storage buffer, not a uniform block.
    let uniform_instances = CLOSEST_HIT.replace(
        "layout(push_constant)",
        "layout(set = 0, binding = 3) uniform Instances { uvec4 instances[4]; };\nlayout(push_constant)",
    );
    refused(
        "uniform-instances",
        &uniform_instances,
        &scene,
        None,
        &["set 0 binding 3 is", "instance data"],
    );
    let floats = CLOSEST_HIT
        .replace(
            "buffer Rays { vec4 rays[]; }",
            "buffer Rays { float rays[]; }",
        )
        .replace("vec4 o = rays[2 * i];", "vec4 o = vec4(rays[8 * i]);")
        .replace(
            "vec4 d = rays[2 * i + 1];",
            "vec4 d = vec4(rays[8 * i + 4]);",
        );
    refused(
        "floats",
        &floats,
        &scene,
        None,
        &["set 0 binding 1", "rays"],
    );
    // Scene keys out of range, named with their place in the file.
    refused(
        "mask",
        CLOSEST_HIT,
        &scene_toml("mask = 256"),
        None,
        &[
            "scene.toml:7:",
            "meshes[0].mask",
            "256 is out of range",
            "0..=255",
        ],
    );
    refused(
        "custom-index",
        CLOSEST_HIT,
        &scene_toml("custom_index = 16777216"),
        None,
        &["meshes[0].custom_index", "0..=16777215"],
    );
    refused(
        "sbt-offset",
        CLOSEST_HIT,
        &scene_toml("sbt_offset = -1"),
        None,
        &["meshes[0].sbt_offset", "out of range"],
    );
    refused(
        "flag",
        CLOSEST_HIT,
        &scene_toml("flags = [\"cull-disable\", \"no-such-flag\"]"),
        None,
        &["meshes[0].flags[1]", "no-such-flag", "force-no-opaque"],
    );
    refused(
        "opaque-type",
        CLOSEST_HIT,
        &scene_toml("opaque = 1"),
        None,
        &["meshes[0].opaque"],
    );
    // The SAH BVH over a non-opaque mesh: its host arrays carry no opaque flag.
    let st = setup(
        "sah",
        CLOSEST_HIT,
        &scene_toml("opaque = false"),
        &grid_rays(),
    );
    let out = vkrt(&[
        "shader-check",
        s(&st.shader),
        s(&st.scene),
        "--rays",
        s(&st.rays),
        "--accel",
        "sah-bvh",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("--accel sah-bvh") && stderr.contains("opaque"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&st.dir);
    // A ray file that is not whole rays.
    refused(
        "rays",
        CLOSEST_HIT,
        &scene,
        Some(&[0u8; 33]),
        &["grid.rays", "33"],
    );
}

#[test]
fn instance_keys_change_nothing_for_other_commands() {
    let rays = grid_rays();
    let keyed = "mask = 3\ncustom_index = 7\nsbt_offset = 2\nflags = [\"cull-disable\", \"force-opaque\"]\nopaque = false";
    let plain = setup("plain", CLOSEST_HIT, &scene_toml(""), &rays);
    let with_keys = setup("keys", CLOSEST_HIT, &scene_toml(keyed), &rays);
    let loaded = vkrt::scene::Scene::load(&with_keys.scene).unwrap().scene;
    let k = loaded.meshes[0].instance;
    assert_eq!(
        (k.mask, k.custom_index, k.sbt_offset, k.flags, k.opaque),
        (3, Some(7), 2, 0x5, false)
    );
    assert_eq!(loaded.meshes[1].instance, Default::default());
    // Written back and read again: the same keys.
    let again = with_keys.dir.join("again.toml");
    std::fs::write(&again, vkrt::scene::toml_format::scene_to_toml(&loaded)).unwrap();
    let reread = vkrt::scene::Scene::load(&again).unwrap().scene;
    assert_eq!(reread.meshes[0].instance, k);
    let mut hits = Vec::new();
    for st in [&plain, &with_keys] {
        let out = st.dir.join("hits.bin");
        if vkrt_ok(&["trace", s(&st.scene), "--rays", s(&st.rays), "-o", s(&out)]).is_none() {
            return;
        }
        hits.push(std::fs::read(&out).unwrap());
    }
    assert_eq!(hits[0], hits[1]);
    let _ = std::fs::remove_dir_all(&plain.dir);
    let _ = std::fs::remove_dir_all(&with_keys.dir);
}

/// A shader that decides candidates itself: non-opaque triangles confirmed where their
/// primitive index is even (an alpha test), boxes generated at the sphere, a cull mask and
/// ray flags per ray; it writes the committed t, custom index, primitive index with the
/// front face, and type with instance id and SBT record offset.
const CANDIDATES: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#extension GL_EXT_ray_flags_primitive_culling : require

layout(local_size_x = 32) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT topLevel;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; float unused; } pc;

const vec4 SPHERES[2] = vec4[2](vec4(-2.0, 0.0, 0.0, 0.5), vec4(2.0, 0.5, -1.0, 0.75));

// A query passed to a function is the caller's query.
void decide(rayQueryEXT q, float tmin, float tmax) {
    if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {
        if ((rayQueryGetIntersectionPrimitiveIndexEXT(q, false) & 1) == 0) {
            rayQueryConfirmIntersectionEXT(q);
        }
        return;
    }
    vec4 sph = SPHERES[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
    vec3 oc = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - sph.xyz;
    vec3 dir = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
    float a = dot(dir, dir);
    float b = dot(oc, dir);
    float disc = b * b - a * (dot(oc, oc) - sph.w * sph.w);
    float best = tmax;
    if (rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT) {
        best = rayQueryGetIntersectionTEXT(q, true);
    }
    if (disc >= 0.0) {
        float t = (-b - sqrt(disc)) / a;
        if (t >= tmin && t <= best) {
            rayQueryGenerateIntersectionEXT(q, t);
        }
    }
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.rayCount) {
        return;
    }
    vec4 o = rays[2 * i];
    vec4 d = rays[2 * i + 1];
    uint flags = gl_RayFlagsNoneEXT;
    if (i % 3u == 1u) {
        flags = gl_RayFlagsCullBackFacingTrianglesEXT;
    } else if (i % 3u == 2u) {
        flags = gl_RayFlagsCullFrontFacingTrianglesEXT;
    }
    if (i % 7u == 3u) {
        flags |= gl_RayFlagsSkipAABBEXT;
    }
    uint mask = (i % 5u == 4u) ? 0x02u : 0xffu;
    rayQueryEXT q;
    rayQueryInitializeEXT(q, topLevel, flags, mask, o.xyz, o.w, d.xyz, d.w);
    while (rayQueryProceedEXT(q)) {
        decide(q, o.w, d.w);
    }
    uint kind = rayQueryGetIntersectionTypeEXT(q, true);
    if (kind == gl_RayQueryCommittedIntersectionNoneEXT) {
        results[i] = uvec4(0u, ~0u, ~0u, 0u);
        return;
    }
    uint front = rayQueryGetIntersectionFrontFaceEXT(q, true) ? 1u : 0u;
    results[i] = uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                       rayQueryGetIntersectionInstanceCustomIndexEXT(q, true),
                       uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)) | (front << 31),
                       kind | (uint(rayQueryGetIntersectionInstanceIdEXT(q, true)) << 8)
                           | (rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(q, true) << 16));
}
"#;

/// The grid from both sides (down from z = 5, up from z = -5).
fn two_sided_rays() -> Vec<Ray> {
    let mut rays = grid_rays();
    let up: Vec<Ray> = rays
        .iter()
        .map(|r| {
            Ray::new(
                Vec3::new(r.origin[0], r.origin[1], -5.0),
                Vec3::Z,
                0.0,
                100.0,
            )
        })
        .collect();
    rays.extend(up);
    rays
}

/// `shader-check SHADER SCENE --rays R -o OUT --json` with `extra` arguments: the parsed
/// report and the records written.
fn check_run(
    name: &str,
    shader: &str,
    scene: &str,
    rays: &[Ray],
    extra: &[&str],
) -> Option<(serde_json::Value, Vec<[u32; 4]>)> {
    let st = setup(name, shader, scene, rays);
    let out_path = st.dir.join("results.bin");
    let mut args = validate();
    args.extend([
        "shader-check",
        s(&st.shader),
        s(&st.scene),
        "--rays",
        s(&st.rays),
    ]);
    args.extend_from_slice(extra);
    args.extend(["-o", s(&out_path), "--json"]);
    let out = vkrt_ok(&args)?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("validation"), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let records = read_records(&out_path);
    let _ = std::fs::remove_dir_all(&st.dir);
    Some((v, records))
}

/// Runs `shader` through both paths; the parsed report and the results written.
fn both(
    name: &str,
    shader: &str,
    scene: &str,
    rays: &[Ray],
) -> Option<(serde_json::Value, Vec<[u32; 4]>)> {
    let (v, records) = check_run(name, shader, scene, rays, &[])?;
    assert_eq!(records.len(), rays.len());
    Some((v, records))
}

#[test]
fn vkrt_and_the_driver_agree_on_a_closest_hit_shader() {
    let rays = grid_rays();
    let Some((v, records)) = both("both-closest", CLOSEST_HIT, &scene_toml(""), &rays) else {
        return;
    };
    assert_eq!(v["mismatching_rays"], 0, "{v}");
    // The records written (the driver's, or vkrt's on a device without ray query) are the
    // scene's answers.
    check_closest_hits(&rays, &records);
    assert!(v["vkrt_ms"].as_f64().is_some(), "{v}");
    assert_eq!(v["native"], has_ray_query(), "{v}");
}

#[test]
fn vkrt_and_the_driver_agree_on_candidates_masks_flags_and_instance_keys() {
    // The first square: non-opaque, seen by mask 1 only, faces flipped, custom index 42 and
    // SBT offset 3; the second: faces never culled, seen by mask 2.
    let keyed =
        "opaque = false\nmask = 1\ncustom_index = 42\nsbt_offset = 3\nflags = [\"flip-facing\"]";
    let scene = scene_toml(keyed).replace(
        "translate = [0, 3, -1]",
        "translate = [0, 3, -1]\nmask = 2\nflags = [\"cull-disable\"]",
    );
    let Some((v, _)) = both("both-candidates", CANDIDATES, &scene, &two_sided_rays()) else {
        return;
    };
    assert_eq!(v["mismatching_rays"], 0, "{v}");
    assert_eq!(v["native"], has_ray_query(), "{v}");
}

/// `CANDIDATES` with opaque rays: facing, masks and instance keys over opaque triangles (the
/// culling flags by ray), the committed getters written.
fn kd_opaque() -> String {
    CANDIDATES.replace(
        "uint flags = gl_RayFlagsNoneEXT;",
        "uint flags = gl_RayFlagsOpaqueEXT;",
    )
}

/// The two squares without the spheres, keyed: a scene of opaque triangles only.
fn opaque_squares() -> String {
    let keyed = "mask = 1\ncustom_index = 42\nsbt_offset = 3\nflags = [\"flip-facing\"]";
    let scene = scene_toml(keyed).replace(
        "translate = [0, 3, -1]",
        "translate = [0, 3, -1]\nmask = 2\nflags = [\"cull-disable\"]",
    );
    scene[..scene.find("[[spheres]]").unwrap()].to_string()
}

/// `shader-check --accel ACCEL --through THROUGH -o`: the report and the records.
fn with_accel(
    name: &str,
    shader: &str,
    scene: &str,
    rays: &[Ray],
    accel: &str,
    through: &str,
) -> Option<(serde_json::Value, Vec<[u32; 4]>)> {
    check_run(
        name,
        shader,
        scene,
        rays,
        &["--accel", accel, "--through", through],
    )
}

#[test]
fn kd_tree_bottom_levels_answer_as_the_bvh_and_the_driver() {
    let rays = two_sided_rays();
    let scene = opaque_squares();
    let Some((kd, kd_records)) =
        with_accel("kd-opaque", &kd_opaque(), &scene, &rays, "kdtree", "both")
    else {
        return;
    };
    assert_eq!(kd["mismatching_rays"], 0, "{kd}");
    let (_, bvh_records) = with_accel(
        "kd-opaque-lbvh",
        &kd_opaque(),
        &scene,
        &rays,
        "lbvh",
        "vkrt",
    )
    .unwrap();
    let (_, kd_vkrt) = with_accel(
        "kd-opaque-vkrt",
        &kd_opaque(),
        &scene,
        &rays,
        "kdtree",
        "vkrt",
    )
    .unwrap();
    assert_eq!(
        kd_vkrt, bvh_records,
        "the kd-tree's answers are the LBVH's, bit for bit"
    );
    if has_ray_query() {
        // -o wrote the driver's there.
        assert_eq!(kd_records, bvh_records);
    }
    let hits = bvh_records.iter().filter(|r| r[3] != 0).count();
    assert!(
        hits > rays.len() / 8 && hits < rays.len(),
        "{hits} of {}",
        rays.len()
    );
}

#[test]
fn a_kd_tree_holds_opaque_triangles_only_for_the_queries() {
    // Spheres in the scene: refused before any GPU work, naming the rule.
    refused_with(
        "kd-spheres",
        CLOSEST_HIT,
        &scene_toml(""),
        None,
        &["--accel", "kdtree"],
        &["--accel kdtree", "opaque triangles"],
    );

    // A ray that makes them candidates (no-opaque) ends its query, exhausted, on a kd-tree
    // level; on a BVH it answers.
    let shader = CANDIDATES
        .replace("uint flags = gl_RayFlagsNoneEXT;", "uint flags = gl_RayFlagsNoOpaqueEXT;")
        .replace(
            "        decide(q, o.w, d.w);\n    }\n",
            "        decide(q, o.w, d.w);\n    }\n    if (vkrtRayQueryExhausted(q)) {\n        results[i] = uvec4(0u, 0u, 0u, 7u);\n        return;\n    }\n",
        );
    assert!(shader.contains("vkrtRayQueryExhausted"));
    let rays = grid_rays();
    let Some((_, kd)) = with_accel(
        "kd-no-opaque",
        &shader,
        &opaque_squares(),
        &rays,
        "kdtree",
        "vkrt",
    ) else {
        return;
    };
    let (_, bvh) = with_accel(
        "kd-no-opaque-lbvh",
        &shader,
        &opaque_squares(),
        &rays,
        "lbvh",
        "vkrt",
    )
    .unwrap();
    let exhausted = kd.iter().filter(|r| r[3] == 7).count();
    assert!(exhausted > 0, "no kd-tree query met a candidate");
    assert!(bvh.iter().all(|r| r[3] != 7), "a BVH query answers");
    for (k, b) in kd.iter().zip(&bvh) {
        assert!(k[3] == 7 || k == b, "{k:?} against {b:?}");
    }
}

#[test]
fn the_spirv_pass_agrees_with_the_driver_without_the_include() {
    let rays = grid_rays();
    let Some((v, records)) = check_run(
        "pass-closest",
        CLOSEST_HIT,
        &scene_toml(""),
        &rays,
        &["--via", "pass"],
    ) else {
        return;
    };
    assert_eq!(v["mismatching_rays"], 0, "{v}");
    check_closest_hits(&rays, &records);
    assert!(v["vkrt_ms"].as_f64().is_some(), "{v}");
    let keyed =
        "opaque = false\nmask = 1\ncustom_index = 42\nsbt_offset = 3\nflags = [\"flip-facing\"]";
    let scene = scene_toml(keyed).replace(
        "translate = [0, 3, -1]",
        "translate = [0, 3, -1]\nmask = 2\nflags = [\"cull-disable\"]",
    );
    let (v, _) = check_run(
        "pass-candidates",
        CANDIDATES,
        &scene,
        &two_sided_rays(),
        &["--via", "pass"],
    )
    .unwrap();
    assert_eq!(v["mismatching_rays"], 0, "{v}");
}

/// A shader that never saw vkrt's include, compiled for the driver's ray query: `vkrt lower`
/// rewrites it, and `shader-check` takes the `.spv` as it is.
#[test]
fn a_spirv_module_from_the_driver_s_compiler_is_lowered_and_checked() {
    let rays = grid_rays();
    let plain = CLOSEST_HIT.replace("#include \"vkrt/ext_ray_query.glsl\"\n", "");
    assert!(!plain.contains("vkrt/"));
    let st = setup("spv", &plain, &scene_toml(""), &rays);
    let spv = st.dir.join("closest.spv");
    let compiled = std::process::Command::new("glslc")
        .args(["--target-env=vulkan1.2", "-fshader-stage=compute", "-o"])
        .arg(&spv)
        .arg(&st.shader)
        .output()
        .expect("glslc (./x setup installs it)");
    assert!(
        compiled.status.success(),
        "{}",
        String::from_utf8_lossy(&compiled.stderr)
    );
    let lowered = st.dir.join("lowered.spv");
    let Some(out) = vkrt_ok(&["lower", s(&spv), "-o", s(&lowered), "--json"]) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["changed"], true, "{v}");
    assert_eq!(v["query_states"], 1, "{v}");
    assert_eq!(v["structures"], 1, "{v}");
    assert!(v["ray_query_instructions"].as_u64().unwrap() >= 8, "{v}");
    assert!(v["functions_linked"].as_u64().unwrap() > 5, "{v}");
    assert!(v["words_out"].as_u64() > v["words_in"].as_u64(), "{v}");
    let words = std::fs::read(&lowered).unwrap();
    assert_eq!(words.len() as u64, 4 * v["words_out"].as_u64().unwrap());

    let out_path = st.dir.join("results.bin");
    let mut args = validate();
    args.extend(["shader-check", s(&spv), s(&st.scene), "--rays", s(&st.rays)]);
    args.extend(["-o", s(&out_path), "--json"]);
    let out = vkrt_ok(&args).unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["mismatching_rays"], 0, "{v}");
    check_closest_hits(&rays, &read_records(&out_path));

    // Not SPIR-V, and SPIR-V cut short: errors, and no output file.
    let junk = st.dir.join("junk.spv");
    std::fs::write(&junk, b"#version 460\n\n\n\n").unwrap();
    let cut = st.dir.join("cut.spv");
    let bytes = std::fs::read(&spv).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 2 / 4 * 4]).unwrap();
    for (input, needle) in [(&junk, "not SPIR-V"), (&cut, "malformed SPIR-V at word")] {
        let target = st.dir.join("never.spv");
        let out = vkrt(&["lower", s(input), "-o", s(&target)]);
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(needle), "{stderr}");
        assert!(!target.exists());
    }
    let _ = std::fs::remove_dir_all(&st.dir);
}

/// `CLOSEST_HIT` in HLSL (DXR 1.1's inline ray tracing), as Slang's compiler takes it.
const CLOSEST_HIT_HLSL: &str = r#"
[[vk::binding(0, 0)]] RaytracingAccelerationStructure scene;
[[vk::binding(1, 0)]] StructuredBuffer<float4> rays;
[[vk::binding(2, 0)]] RWStructuredBuffer<uint4> results;
[[vk::push_constant]] cbuffer Count { uint rayCount; };

static const float4 SPHERES[2] = { float4(-2.0, 0.0, 0.0, 0.5), float4(2.0, 0.5, -1.0, 0.75) };

[numthreads(64, 1, 1)]
void main(uint3 id : SV_DispatchThreadID) {
    uint i = id.x;
    if (i >= rayCount) return;
    float4 o = rays[2 * i];
    float4 d = rays[2 * i + 1];
    RayDesc ray;
    ray.Origin = o.xyz;
    ray.TMin = o.w;
    ray.Direction = d.xyz;
    ray.TMax = d.w;
    RayQuery<RAY_FLAG_FORCE_OPAQUE> q;
    q.TraceRayInline(scene, RAY_FLAG_NONE, 0xff, ray);
    while (q.Proceed()) {
        if (q.CandidateType() != CANDIDATE_PROCEDURAL_PRIMITIVE) continue;
        float4 sph = SPHERES[q.CandidatePrimitiveIndex()];
        float3 oc = q.CandidateObjectRayOrigin() - sph.xyz;
        float3 dir = q.CandidateObjectRayDirection();
        float a = dot(dir, dir);
        float b = dot(oc, dir);
        float c = dot(oc, oc) - sph.w * sph.w;
        float disc = b * b - a * c;
        float best = q.CommittedStatus() != COMMITTED_NOTHING ? q.CommittedRayT() : d.w;
        if (disc >= 0.0) {
            float t = (-b - sqrt(disc)) / a;
            if (t >= o.w && t <= best) q.CommitProceduralPrimitiveHit(t);
        }
    }
    uint kind = q.CommittedStatus();
    if (kind == COMMITTED_NOTHING) {
        results[i] = uint4(0, 0xffffffff, 0xffffffff, 0);
    } else {
        results[i] = uint4(asuint(q.CommittedRayT()), q.CommittedInstanceIndex(),
                           q.CommittedPrimitiveIndex(), kind);
    }
}
"#;

/// The same in Slang's own dialect: a generic helper over the query, `let` and `var`.
const CLOSEST_HIT_SLANG: &str = r#"
[[vk::binding(0, 0)]] RaytracingAccelerationStructure scene;
[[vk::binding(1, 0)]] StructuredBuffer<float4> rays;
[[vk::binding(2, 0)]] RWStructuredBuffer<uint4> results;
[[vk::push_constant]] cbuffer Count { uint rayCount; };

static const float4 SPHERES[2] = { float4(-2.0, 0.0, 0.0, 0.5), float4(2.0, 0.5, -1.0, 0.75) };

float sphereT(float4 sph, float3 origin, float3 dir, float tMin, float best) {
    let oc = origin - sph.xyz;
    let a = dot(dir, dir);
    let b = dot(oc, dir);
    let c = dot(oc, oc) - sph.w * sph.w;
    let disc = b * b - a * c;
    if (disc < 0.0) return -1.0;
    let t = (-b - sqrt(disc)) / a;
    return (t >= tMin && t <= best) ? t : -1.0;
}

void walk<let F : int>(inout RayQuery<F> q, float tMin, float tMax) {
    while (q.Proceed()) {
        if (q.CandidateType() != CANDIDATE_PROCEDURAL_PRIMITIVE) continue;
        let best = q.CommittedStatus() != COMMITTED_NOTHING ? q.CommittedRayT() : tMax;
        let t = sphereT(SPHERES[q.CandidatePrimitiveIndex()], q.CandidateObjectRayOrigin(),
                        q.CandidateObjectRayDirection(), tMin, best);
        if (t >= 0.0) q.CommitProceduralPrimitiveHit(t);
    }
}

[shader("compute")]
[numthreads(64, 1, 1)]
void main(uint3 id : SV_DispatchThreadID) {
    let i = id.x;
    if (i >= rayCount) return;
    let o = rays[2 * i];
    let d = rays[2 * i + 1];
    var ray : RayDesc;
    ray.Origin = o.xyz;
    ray.TMin = o.w;
    ray.Direction = d.xyz;
    ray.TMax = d.w;
    var q : RayQuery<RAY_FLAG_FORCE_OPAQUE>;
    q.TraceRayInline(scene, RAY_FLAG_NONE, 0xff, ray);
    walk(q, o.w, d.w);
    let kind = q.CommittedStatus();
    results[i] = kind == COMMITTED_NOTHING
        ? uint4(0, 0xffffffff, 0xffffffff, 0)
        : uint4(asuint(q.CommittedRayT()), q.CommittedInstanceIndex(), q.CommittedPrimitiveIndex(), kind);
}
"#;

/// Slang and HLSL, compiled by Slang's compiler for the driver's ray query and lowered by
/// the pass: the same answers as the driver's, and the scene's. Where no Slang compiler can
/// be run (VKRT_SLANGC unset and no slangc on the PATH; `./x setup` fetches one), it says so.
#[test]
fn slang_and_hlsl_shaders_run_through_the_pass() {
    let have = std::env::var_os("VKRT_SLANGC").is_some()
        || std::process::Command::new("slangc")
            .arg("-v")
            .output()
            .is_ok();
    if !have {
        eprintln!(
            "note: no Slang compiler (VKRT_SLANGC or slangc): Slang and HLSL are not checked"
        );
        return;
    }
    let rays = grid_rays();
    for (name, source) in [
        ("closest.hlsl", CLOSEST_HIT_HLSL),
        ("closest.slang", CLOSEST_HIT_SLANG),
    ] {
        let st = setup(name, source, &scene_toml(""), &rays);
        let shader = st.dir.join(name);
        std::fs::write(&shader, source).unwrap();
        let out_path = st.dir.join("results.bin");
        let mut args = validate();
        args.extend([
            "shader-check",
            s(&shader),
            s(&st.scene),
            "--rays",
            s(&st.rays),
        ]);
        args.extend(["-o", s(&out_path), "--json"]);
        let Some(out) = vkrt_ok(&args) else {
            return;
        };
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["mismatching_rays"], 0, "{name}: {v}");
        assert!(v["vkrt_ms"].as_f64().is_some(), "{name}: {v}");
        check_closest_hits(&rays, &read_records(&out_path));
        // The module Slang's compiler wrote, lowered by `vkrt lower`, is valid SPIR-V.
        let (spv, lowered) = (st.dir.join("native.spv"), st.dir.join("lowered.spv"));
        let slangc = std::env::var("VKRT_SLANGC").unwrap_or_else(|_| "slangc".into());
        let compiled = std::process::Command::new(slangc)
            .arg(&shader)
            .args([
                "-target", "spirv", "-entry", "main", "-stage", "compute", "-o",
            ])
            .arg(&spv)
            .output()
            .unwrap();
        assert!(
            compiled.status.success(),
            "{}",
            String::from_utf8_lossy(&compiled.stderr)
        );
        vkrt_ok(&["lower", s(&spv), "-o", s(&lowered)]).unwrap();
        let val = std::process::Command::new("spirv-val")
            .args(["--target-env", "vulkan1.2"])
            .arg(&lowered)
            .output()
            .expect("spirv-val (./x setup installs spirv-tools)");
        assert!(
            val.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&val.stderr)
        );
        let _ = std::fs::remove_dir_all(&st.dir);
    }
}

/// `CLOSEST_HIT` as a renderer's image shader: 8 x 8 pixels a workgroup, the pixel from
/// `gl_GlobalInvocationID.xy`, the image's width the push block's second word.
fn closest_hit_2d() -> String {
    let s = CLOSEST_HIT
        .replace(
            "layout(local_size_x = 64) in;",
            "layout(local_size_x = 8, local_size_y = 8) in;",
        )
        .replace(
            "layout(push_constant) uniform Count { uint rayCount; };",
            "layout(push_constant) uniform Count { uint rayCount; uint width; };",
        )
        .replace(
            "    uint i = gl_GlobalInvocationID.x;\n",
            "    uvec2 px = gl_GlobalInvocationID.xy;\n    if (px.x >= width) {\n        return;\n    }\n    uint i = px.y * width + px.x;\n",
        );
    assert!(
        s.contains("local_size_y = 8") && s.contains("uint width;") && s.contains("px.y * width")
    );
    s
}

#[test]
fn a_two_dimensional_shader_runs_over_the_image_s_rows() {
    let rays = grid_rays(); // 16 x 16, row by row
    for via in ["include", "pass"] {
        let Some((v, records)) = check_run(
            &format!("grid-{via}"),
            &closest_hit_2d(),
            &scene_toml(""),
            &rays,
            &["--width", "16", "--via", via],
        ) else {
            return;
        };
        assert_eq!(v["mismatching_rays"], 0, "{via}: {v}");
        check_closest_hits(&rays, &records);
    }
    // Without the width, and a width for a one-dimensional shader: refused before any GPU
    // work, nothing written.
    refused_with(
        "grid-no-width",
        &closest_hit_2d(),
        &scene_toml(""),
        None,
        &["--through", "vkrt"],
        &["two-dimensional", "--width"],
    );
    refused_with(
        "grid-1d-width",
        CLOSEST_HIT,
        &scene_toml(""),
        None,
        &["--through", "vkrt", "--width", "16"],
        &["--width is for a shader with a two-dimensional workgroup"],
    );
}
