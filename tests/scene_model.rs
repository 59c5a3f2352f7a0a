//! Scene model, generators, flattening, effects and summary.

use std::collections::HashMap;
use std::time::Instant;

use glam::Vec3;
use vkrt::scene::gen;
use vkrt::scene::{
    Camera, Effects, Light, Material, Mesh, MeshMaterials, Motion, Orbit, Scene, SceneError,
    Sphere, Transform,
};

/// Every undirected edge used by exactly two triangles, in opposite
/// directions (closed, consistently oriented 2-manifold).
fn assert_watertight(mesh: &Mesh) {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in mesh.indices.iter() {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
        assert_eq!(
            directed.get(&(b, a)),
            Some(&1),
            "edge {a}-{b} is not shared by exactly two oppositely wound triangles"
        );
    }
    let edges = directed.len() / 2;
    let euler = mesh.positions.len() as i64 - edges as i64 + mesh.indices.len() as i64;
    assert_eq!(euler, 2, "Euler characteristic of a sphere");
}

fn assert_outward_unit_sphere(mesh: &Mesh) {
    for t in mesh.indices.iter() {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(c - a);
        assert!(n.dot(a + b + c) > 0.0, "inward-facing triangle {t:?}");
    }
    for p in mesh.positions.iter() {
        assert!(
            (p.length() - 1.0).abs() < 1e-5,
            "vertex {p} off the unit sphere"
        );
    }
}

#[test]
fn icosphere_counts_and_watertight() {
    for s in 0..=5 {
        let m = gen::icosphere(s).unwrap();
        assert_eq!(m.indices.len() as u64, 20 * 4u64.pow(s));
        assert_eq!(m.indices.len() as u64, gen::icosphere_triangle_count(s));
        assert_eq!(m.positions.len() as u64, 10 * 4u64.pow(s) + 2);
        assert_eq!(m.normals.len(), m.positions.len());
        assert_watertight(&m);
        assert_outward_unit_sphere(&m);
    }
    // Frequencies that are not powers of two are closed too.
    for f in [3, 5, 7, 12] {
        let m = gen::geodesic_sphere(f).unwrap();
        assert_eq!(m.indices.len() as u64, 20 * (f * f) as u64);
        assert_watertight(&m);
        assert_outward_unit_sphere(&m);
    }
}

#[test]
fn icosphere_with_at_least_is_tight() {
    for n in [1u64, 20, 21, 1000, 12_345, 1_800_000] {
        let m = gen::icosphere_with_at_least(n).unwrap();
        let got = m.indices.len() as u64;
        assert!(got >= n, "{got} < {n}");
        // The next smaller frequency would be below n.
        let f = ((got / 20) as f64).sqrt().round() as u32;
        assert_eq!(gen::geodesic_triangle_count(f), got);
        assert!(f == 1 || gen::geodesic_triangle_count(f - 1) < n);
    }
    // Sochora's (2013) "Icosahedron": 1.8 M triangles exactly (frequency 300).
    assert_eq!(
        gen::icosphere_with_at_least(1_800_000)
            .unwrap()
            .indices
            .len(),
        1_800_000
    );
}

#[test]
fn two_million_triangles_fast() {
    let t0 = Instant::now();
    let m = gen::icosphere_with_at_least(2_000_000).unwrap();
    let dt = t0.elapsed();
    assert!(m.indices.len() >= 2_000_000);
    println!(
        "icosphere {} triangles in {:.1} ms",
        m.indices.len(),
        dt.as_secs_f64() * 1e3
    );
    if !cfg!(debug_assertions) {
        assert!(dt.as_secs_f64() < 1.0, "took {dt:?}");
    }
    // Spot-check closure on the big one without a full hash of 6 M edges:
    // V − E + F = 2 with E = 3F/2 for a closed triangle mesh.
    let (v, f) = (m.positions.len() as i64, m.indices.len() as i64);
    assert_eq!(v - 3 * f / 2 + f, 2);
}

#[test]
fn icosphere_too_large_is_an_error() {
    let e = gen::icosphere(10).unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::TooLarge {
                what: "triangle",
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("icosphere"), "{e}");
    assert!(gen::icosphere_with_at_least(u64::MAX).is_err());
    assert!(gen::geodesic_sphere(0).is_err());
}

#[test]
fn random_soup_is_deterministic_and_non_degenerate() {
    let a = gen::random_soup(10_000, 7).unwrap();
    let b = gen::random_soup(10_000, 7).unwrap();
    let c = gen::random_soup(10_000, 8).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.positions, c.positions);
    assert_eq!(a.indices.len(), 10_000);
    assert_eq!(a.positions.len(), 30_000);
    for t in a.indices.iter() {
        let [p, q, r] = t.map(|i| a.positions[i as usize]);
        assert!((q - p).cross(r - p).length() > 0.0);
        for v in [p, q, r] {
            assert!(v.abs().max_element() < 1.5, "{v}");
        }
    }
    // Pinned values: the generator must not change silently (benchmarks and
    // accel tests compare across versions).
    let first = gen::random_soup(1, 0).unwrap().positions;
    let mut rng = gen::Rng::new(0);
    let center = rng.vec3_signed();
    assert_eq!(first[0], center + rng.vec3_signed() * 2.0);
    assert_eq!(gen::Rng::new(0).next_u64(), 0xE220_A839_7B1D_CDAF);
    assert_eq!(gen::Rng::new(1).next_u64(), 0x910A_2DEC_8902_5CC1);
}

#[test]
fn rng_ranges() {
    let mut r = gen::Rng::new(123);
    for _ in 0..100_000 {
        let f = r.next_f32();
        assert!((0.0..1.0).contains(&f));
        assert!(r.below(10) < 10);
    }
}

#[test]
fn integer_grid_has_integer_vertices_and_right_counts() {
    let m = gen::integer_grid(7, 3).unwrap();
    assert_eq!(m.indices.len(), 2 * 7 * 3);
    assert_eq!(m.positions.len(), 8 * 4);
    for p in m.positions.iter() {
        assert_eq!(*p, p.round(), "{p} not on integer coordinates");
        assert_eq!(p.z, 0.0);
    }
    // Facing +Z, covering exactly the 7 × 3 rectangle.
    let mut area = 0.0;
    for t in m.indices.iter() {
        let [a, b, c] = t.map(|i| m.positions[i as usize]);
        let n = (b - a).cross(c - a);
        assert!(n.z > 0.0);
        area += n.z * 0.5;
    }
    assert_eq!(area, 21.0);
    // Interior edges shared by exactly two triangles, boundary edges by one.
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for t in m.indices.iter() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let boundary = edges.values().filter(|&&n| n == 1).count();
    assert_eq!(boundary, 2 * (7 + 3));
    assert!(edges.values().all(|&n| n <= 2));
    assert!(gen::integer_grid(0, 5).is_err());
}

#[test]
fn sphere_flake_counts() {
    for d in 0..=4 {
        let s = gen::sphere_flake_spheres(d).unwrap();
        assert_eq!(s.len() as u64, (9u64.pow(d + 1) - 1) / 8);
        assert_eq!(s.len() as u64, gen::sphere_flake_count(d));
    }
    let s = gen::sphere_flake_spheres(2).unwrap();
    // Children touch their parent: |c_child − c_parent| = r + r/3.
    assert!((s[1].center.length() - 4.0 / 3.0).abs() < 1e-5);
    assert!((s[1].radius - 1.0 / 3.0).abs() < 1e-6);
    // No two spheres of the flake overlap.
    for i in 0..s.len() {
        for j in i + 1..s.len() {
            let d = (s[i].center - s[j].center).length();
            assert!(d >= s[i].radius + s[j].radius - 1e-4, "{i} and {j} overlap");
        }
    }
    assert!(gen::sphere_flake_spheres(7).is_err());
    let mesh = gen::sphere_flake_mesh(2, 1).unwrap();
    assert_eq!(mesh.indices.len(), 91 * 80);
    let mut scene = gen::sphere_flake(3).unwrap();
    scene.validate().unwrap();
    assert_eq!(scene.spheres.len(), 820);
}

#[test]
fn cornell_box_default_scene() {
    let mut s = Scene::default_scene();
    let warnings = s.validate().unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(s.triangle_count(), 10);
    assert_eq!(s.spheres.len(), 2);
    let e = s.effects();
    assert_eq!(
        e.names(),
        ["soft_shadows", "reflection", "refraction", "antialiasing"]
    );
    assert!(e.needs_multiple_samples());
    // The spheres sit on the floor and inside the room.
    for sp in &s.spheres {
        assert!((sp.center.y - sp.radius - -1.0).abs() < 0.25);
        assert!(sp.center.abs().max_element() + sp.radius <= 1.0);
    }
    // Walls face into the room.
    for (tri, n) in s
        .triangles_world(0.0)
        .iter()
        .zip(s.triangle_normals_world(0.0))
    {
        let centroid = (tri[0] + tri[1] + tri[2]) / 3.0;
        assert!(n[0].dot(-centroid) > 0.0, "wall at {centroid} faces out");
    }
    // The camera sees the whole opening.
    let (f, _, _) = s.camera.basis();
    assert!((f - Vec3::NEG_Z).length() < 1e-6, "{f}");
}

#[test]
fn dynamic_ring_animates() {
    let model = gen::icosphere(3).unwrap();
    let mut s = gen::dynamic_ring(model, 8).unwrap();
    s.validate().unwrap();
    assert_eq!(s.spheres.len(), 8);
    assert_eq!(s.triangle_count(), 10 + 1280);
    let e = s.effects();
    assert!(e.reflection && e.refraction && e.hard_shadows);
    assert!(!e.motion_blur, "shutter is closed: animation, not blur");
    // Model scaled into the unit sphere, standing on the floor (y = 0).
    let model_tris = &s.triangles_world(0.0)[10..];
    let min_y = model_tris
        .iter()
        .flatten()
        .map(|p| p.y)
        .fold(f32::MAX, f32::min);
    assert!(min_y.abs() < 1e-5, "{min_y}");
    // Spheres orbit at 45°/s around the Y axis: after 2 s they are a
    // quarter turn further, at the same height and distance.
    let t0 = s.spheres_at(0.0);
    let t2 = s.spheres_at(2.0);
    for (a, b) in t0.iter().zip(&t2) {
        assert!((a.center.length() - b.center.length()).abs() < 1e-4);
        assert!((a.center.y - b.center.y).abs() < 1e-6);
        let (pa, pb) = (a.center.with_y(0.0), b.center.with_y(0.0));
        assert!(pa.dot(pb).abs() < 1e-4, "not a quarter turn: {pa} {pb}");
        // Right-hand rule about +Y: +X goes to −Z.
        assert!(pa.cross(pb).y > 0.0);
    }
    // After 8 s a full turn: back where they started.
    for (a, b) in t0.iter().zip(&s.spheres_at(8.0)) {
        assert!((a.center - b.center).length() < 1e-4);
    }
    // Opening the shutter turns on motion blur.
    s.camera.shutter_close = 1.0 / 30.0;
    assert!(s.effects().motion_blur);
}

#[test]
fn transform_order_and_rotation_axes() {
    let rx = Transform {
        rotate: Vec3::new(90.0, 0.0, 0.0),
        ..Transform::IDENTITY
    };
    assert!((rx.matrix().transform_point3(Vec3::Y) - Vec3::Z).length() < 1e-6);
    let ry = Transform {
        rotate: Vec3::new(0.0, 90.0, 0.0),
        ..Transform::IDENTITY
    };
    assert!((ry.matrix().transform_point3(Vec3::X) - Vec3::NEG_Z).length() < 1e-6);
    // X first, then Y (fixed axes): Y → Z → X.
    let rxy = Transform {
        rotate: Vec3::new(90.0, 90.0, 0.0),
        ..Transform::IDENTITY
    };
    assert!((rxy.matrix().transform_point3(Vec3::Y) - Vec3::X).length() < 1e-6);
    // Scale, then rotate, then translate.
    let t = Transform {
        translate: Vec3::new(10.0, 0.0, 0.0),
        rotate: Vec3::new(0.0, 0.0, 90.0),
        scale: Vec3::new(2.0, 1.0, 1.0),
    };
    let p = t.matrix().transform_point3(Vec3::X);
    assert!((p - Vec3::new(10.0, 2.0, 0.0)).length() < 1e-5, "{p}");
}

fn one_triangle_scene() -> Scene {
    let mut mesh = Mesh::new(
        "tri",
        vec![Vec3::ZERO, Vec3::X, Vec3::Y],
        vec![[0, 1, 2]],
        0,
    );
    mesh.transform.translate = Vec3::new(0.0, 0.0, -1.0);
    mesh.transform.scale = Vec3::new(2.0, 1.0, 1.0);
    Scene::from_geometry(vec![mesh], vec![], vec![Material::default()])
}

#[test]
fn flattening_applies_transform_and_motion() {
    let mut s = one_triangle_scene();
    s.meshes[0].motion = Motion {
        velocity: Vec3::new(0.0, 1.0, 0.0),
        orbit: None,
    };
    let t0 = s.triangles_world(0.0);
    assert_eq!(
        t0,
        vec![[
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(2.0, 0.0, -1.0),
            Vec3::new(0.0, 1.0, -1.0)
        ]]
    );
    let t1 = s.triangles_world(0.5);
    assert_eq!(t1[0][1], Vec3::new(2.0, 0.5, -1.0));
    assert_eq!(s.triangle_materials(), vec![0]);
    // Face normal when the mesh has none; non-uniform scale handled with the
    // inverse transpose when it does.
    assert_eq!(s.triangle_normals_world(0.0)[0], [Vec3::Z; 3]);
    s.meshes[0].normals = vec![Vec3::new(1.0, 0.0, 1.0).normalize(); 3].into();
    let n = s.triangle_normals_world(0.0)[0][0];
    assert!(
        (n - Vec3::new(1.0, 0.0, 2.0).normalize()).length() < 1e-6,
        "{n}"
    );
    // Per-triangle materials come out in order.
    s.materials.push(Material::default());
    s.meshes[0].materials = MeshMaterials::PerTriangle(vec![1].into());
    assert_eq!(s.triangle_materials(), vec![1]);
}

#[test]
fn swept_bounds_cover_motion() {
    let mut s = one_triangle_scene();
    s.spheres.push(Sphere {
        center: Vec3::new(3.0, 0.0, 0.0),
        radius: 0.5,
        material: 0,
        motion: Motion {
            velocity: Vec3::ZERO,
            orbit: Some(Orbit {
                center: Vec3::ZERO,
                axis: Vec3::Y,
                degrees_per_second: 90.0,
            }),
        },
    });
    s.camera.shutter_open = 0.0;
    s.camera.shutter_close = 2.0; // half a turn
    let b = s.swept_bounds();
    for k in 0..=200 {
        let t = 2.0 * k as f32 / 200.0;
        for sp in s.spheres_at(t) {
            assert!(sp.center.x - 0.5 >= b.min.x - 1e-4 && sp.center.x + 0.5 <= b.max.x + 1e-4);
            assert!(sp.center.z - 0.5 >= b.min.z - 1e-4 && sp.center.z + 0.5 <= b.max.z + 1e-4);
        }
    }
    // Half a turn from +X through −Z to −X: x spans [−3.5, 3.5], z [−3.5, 0.5].
    assert!(b.min.x <= -3.5 && b.max.x >= 3.5 && b.min.z <= -3.5);
    assert!(b.max.z < 1.1, "{b:?} too loose");
}

#[test]
fn effects_follow_the_data() {
    let base = || {
        let mut s = one_triangle_scene();
        s.lights.clear();
        s.settings.spp = 1;
        s
    };
    assert!(base().effects().names().is_empty());

    let mut s = base();
    s.lights.push(Light::Point {
        position: Vec3::ONE,
        color: Vec3::ONE,
        intensity: 1.0,
    });
    assert_eq!(s.effects().names(), ["hard_shadows"]);
    s.lights[0] = Light::Point {
        position: Vec3::ONE,
        color: Vec3::ONE,
        intensity: 0.0,
    };
    assert!(
        !s.effects().hard_shadows,
        "a dark light casts no shadow rays"
    );

    let mut s = base();
    s.lights.push(Light::Sphere {
        center: Vec3::ONE,
        radius: 0.1,
        color: Vec3::ONE,
        intensity: 1.0,
    });
    assert_eq!(s.effects().names(), ["soft_shadows"]);

    let mut s = base();
    s.materials[0] = Material::mirror("m", Vec3::ONE);
    assert_eq!(s.effects().names(), ["reflection"]);
    s.materials[0].roughness = 0.3;
    assert_eq!(s.effects().names(), ["glossy"]);
    s.settings.max_depth = 0;
    assert!(
        s.effects().names().is_empty(),
        "no bounces, no secondary rays"
    );

    let mut s = base();
    s.materials[0] = Material::glass("g", 1.5);
    assert_eq!(s.effects().names(), ["reflection", "refraction"]);
    s.materials[0].fresnel = false;
    assert_eq!(s.effects().names(), ["refraction"]);

    let mut s = base();
    s.materials.push(Material::emissive("e", Vec3::ONE));
    assert!(!s.effects().emission, "unused materials do not count");
    s.materials[0].emission = Vec3::ONE;
    assert_eq!(s.effects().names(), ["emission"]);

    let mut s = base();
    s.settings.spp = 4;
    assert_eq!(s.effects().names(), ["antialiasing"]);
    s.settings.antialias = false;
    assert!(s.effects().names().is_empty());

    let mut s = base();
    s.camera.aperture_radius = 0.1;
    assert_eq!(s.effects().names(), ["depth_of_field"]);

    let mut s = base();
    s.meshes[0].motion.velocity = Vec3::X;
    assert!(s.effects().names().is_empty(), "closed shutter");
    s.camera.shutter_close = 0.1;
    assert_eq!(s.effects().names(), ["motion_blur"]);

    let mut s = base();
    s.settings.ao.enabled = true;
    assert_eq!(s.effects().names(), ["ambient_occlusion"]);

    let all = Effects {
        hard_shadows: true,
        soft_shadows: true,
        reflection: true,
        glossy: true,
        refraction: true,
        antialiasing: true,
        depth_of_field: true,
        motion_blur: true,
        ambient_occlusion: true,
        emission: true,
    };
    assert_eq!(all.names(), Effects::ALL_NAMES);
    for n in Effects::ALL_NAMES {
        assert!(all.has(n) && !Effects::default().has(n));
    }
}

#[test]
fn summary_json_and_text() {
    let s = Scene::default_scene();
    let sum = s.summary();
    assert_eq!(sum.triangles, 10);
    assert_eq!(sum.spheres, 2);
    assert_eq!(sum.lights, 1);
    assert_eq!(sum.materials, 5);
    assert_eq!(sum.bounds.min, [-1.0, -1.0, -1.0]);
    assert_eq!(sum.bounds.max, [1.0, 1.0, 1.0]);
    let json: serde_json::Value = serde_json::to_value(&sum).unwrap();
    for k in [
        "triangles",
        "spheres",
        "lights",
        "materials",
        "bounds",
        "effects",
    ] {
        assert!(json.get(k).is_some(), "missing {k} in {json}");
    }
    assert_eq!(json["bounds"]["min"], serde_json::json!([-1.0, -1.0, -1.0]));
    assert_eq!(
        json["effects"],
        serde_json::json!(["soft_shadows", "reflection", "refraction", "antialiasing"])
    );
    let text = sum.to_text();
    assert!(text.contains("triangles: 10"), "{text}");
    assert!(
        text.contains("soft_shadows, reflection, refraction, antialiasing"),
        "{text}"
    );
}

#[test]
fn hand_built_scene_validation() {
    // A programmatic scene goes through the same checks as loaded ones.
    let mut s = one_triangle_scene();
    s.spheres.push(Sphere::new(Vec3::ZERO, -1.0, 0));
    let e = s.validate().unwrap_err();
    assert!(e.to_string().contains("spheres[0].radius"), "{e}");
    let mut s = one_triangle_scene();
    s.camera = Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 40.0);
    let e = s.validate().unwrap_err();
    assert!(e.to_string().contains("camera.look_at"), "{e}");
    let mut s = one_triangle_scene();
    std::sync::Arc::make_mut(&mut s.meshes[0].indices).push([0, 1, 3]);
    let e = s.validate().unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::IndexOutOfRange {
                index: 3,
                len: 3,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("meshes[0].indices[1]"), "{e}");
}

#[test]
fn zero_area_triangles_dropped_and_counted() {
    let mut s = one_triangle_scene();
    let m = &mut s.meshes[0];
    std::sync::Arc::make_mut(&mut m.positions).push(Vec3::new(2.0, 0.0, 0.0)); // collinear with 0 and X
    std::sync::Arc::make_mut(&mut m.indices).extend([[0, 0, 1], [0, 1, 3], [1, 2, 2]]);
    m.materials = MeshMaterials::PerTriangle(vec![0, 0, 0, 0].into());
    let warnings = s.validate().unwrap();
    assert_eq!(*s.meshes[0].indices, vec![[0, 1, 2]]);
    assert_eq!(
        s.meshes[0].materials,
        MeshMaterials::PerTriangle(vec![0].into())
    );
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("dropped 3 zero-area triangles")),
        "{warnings:?}"
    );
    // A tiny but valid triangle is kept.
    let mut s = one_triangle_scene();
    s.meshes[0].positions = vec![
        Vec3::ZERO,
        Vec3::new(1e-20, 0.0, 0.0),
        Vec3::new(0.0, 1e-20, 0.0),
    ]
    .into();
    s.meshes[0].transform = Transform::IDENTITY;
    s.validate().unwrap();
    assert_eq!(s.triangle_count(), 1);
    // All degenerate: the scene is empty, and the message says why.
    let mut s = one_triangle_scene();
    s.meshes[0].indices = vec![[0, 0, 0]].into();
    let e = s.validate().unwrap_err();
    assert!(matches!(e, SceneError::Empty { .. }));
    assert!(e.to_string().contains("zero area"), "{e}");
}
