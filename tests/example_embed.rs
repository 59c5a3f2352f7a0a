//! `examples/embed.rs`, run as a test: a host program that owns its instance, device,
//! queue, allocator and command buffer records vkrt's LBVH build and trace between its own
//! passes, submits once, and reads back hits equal to brute force — with the validation
//! layer (synchronization validation on) silent from instance creation to destruction.

#[allow(dead_code, reason = "the example's `main` is not called here")]
#[path = "../examples/embed.rs"]
mod embed;

mod common;

use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::Validation;
use vkrt::trace::cpu;

#[test]
fn the_embedding_example_traces_like_brute_force_and_validation_stays_silent() {
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let rays = embed::rays_toward(&tris, 1000, 7);
    // On when the layer is installed and VKRT_VALIDATION is not 0, as in every GPU test.
    let summary = match embed::run(&tris, &rays, Validation::FromEnv) {
        Ok(s) => s,
        Err(e) if std::env::var("VKRT_ALLOW_NO_GPU").is_ok_and(|v| v == "1") => {
            eprintln!("skipped: {e} and VKRT_ALLOW_NO_GPU=1");
            return;
        }
        Err(e) => panic!("the embedding example failed: {e}"),
    };
    if !summary.validation {
        eprintln!("note: validation layer not enabled (not installed or VKRT_VALIDATION=0)");
    }
    assert!(
        summary.messages.is_empty(),
        "validation reported {} message(s):\n{}",
        summary.messages.len(),
        summary.messages.join("\n")
    );
    assert_eq!(summary.vkrt_submits, 0, "vkrt submitted on its own");
    assert_eq!(summary.exhausted, 0);
    assert_eq!(summary.hits.len(), rays.len());

    let g = TraceGeometry::from_triangles(&tris);
    let mut hits = 0;
    for (ray, h) in rays.iter().zip(&summary.hits) {
        let b = cpu::brute_force(&g, ray, 0.0, &summary.options);
        assert_eq!(h.is_hit(), b.is_hit(), "{ray:?}");
        if h.is_hit() {
            hits += 1;
            assert!((h.t - b.t).abs() <= 1e-5 * b.t, "t {} vs {}", h.t, b.t);
        }
    }
    assert!(hits > 500, "{hits} hits of {}", rays.len());

    // The host's own passes and vkrt's are in the profile of the host's command buffer.
    let top: Vec<&str> = summary
        .profile
        .passes
        .iter()
        .filter(|p| p.depth == 0)
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(top, ["host.rays", "build", "trace", "host.readback"]);
}
