//! `examples/own_shader.rs`, run as a test: a host that owns its device, memory and command
//! buffer builds vkrt's structures from its own vertex and index buffers into memory it
//! allocated at the sizes vkrt reported, and traces them from its own compute shader through
//! `vkrt/ray_query.glsl` (the driver's structure too where the device has ray query); every
//! closest hit (t, geometry, primitive) and every occlusion
//! answer equals brute force, vkrt submits, uploads and allocates nothing, and the validation
//! layer stays silent.

#[allow(dead_code, reason = "the example's `main` is not called here")]
#[path = "../examples/own_shader.rs"]
mod own_shader;

mod common;

use vkrt::accel::device::AccelKind;
use vkrt::gpu::Validation;

#[test]
fn a_renderers_own_shader_traces_vkrt_structures_like_brute_force() {
    let _turn = common::vulkan_turn();
    let mesh = own_shader::load_mesh(common::bunny_path()).unwrap();
    let rays = own_shader::ao_rays(&mesh, if common::quick() { 256 } else { 1024 }, 7);
    let kinds = [
        AccelKind::KdTree,
        AccelKind::Lbvh,
        AccelKind::Ploc,
        AccelKind::Driver,
    ];
    let s = match own_shader::run(&mesh, &rays, &kinds, Validation::FromEnv) {
        Ok(s) => s,
        Err(e) if std::env::var("VKRT_ALLOW_NO_GPU").is_ok_and(|v| v == "1") => {
            eprintln!("skipped: {e} and VKRT_ALLOW_NO_GPU=1");
            return;
        }
        Err(e) => panic!("the own-shader example failed: {e}"),
    };
    assert!(
        s.messages.is_empty(),
        "validation reported {} message(s):\n{}",
        s.messages.len(),
        s.messages.join("\n")
    );
    // The driver's structure where the host could enable the driver's ray query.
    assert_eq!(s.kinds.len(), 3 + s.ray_query as usize);
    assert_eq!(s.kinds.contains_key("driver"), s.ray_query);
    for (name, k) in &s.kinds {
        assert_eq!(k.rays, rays.len(), "{name}");
        assert_eq!(
            k.mismatches,
            Some(0),
            "{name}: closest hits differ from brute force"
        );
        assert_eq!(
            k.any_mismatches,
            Some(0),
            "{name}: occlusion differs from brute force"
        );
        assert_eq!(k.exhausted, 0, "{name}");
    }
    assert_eq!(s.vkrt_submits, 0, "vkrt submitted on its own");
    assert_eq!(s.vkrt_upload_bytes, 0, "vkrt uploaded");
    assert_eq!(s.vkrt_allocations, 0, "vkrt allocated device memory");
}
