//! Whole scenes: the embedded Cornell box and Kolodzey's dynamic scene.

use glam::Vec3;

use super::too_large;
use crate::scene::error::{Origin, SceneError};
use crate::scene::limits::MAX_SPHERES;
use crate::scene::material::Material;
use crate::scene::model::{
    Camera, Light, MaterialId, Mesh, MeshMaterials, Motion, Orbit, RenderSettings, Sphere,
    Transform,
};
use crate::scene::Scene;

/// Append the parallelogram `corner + u·edge_u + v·edge_v` as two
/// triangles facing `edge_u × edge_v`.
fn push_quad(
    positions: &mut Vec<Vec3>,
    indices: &mut Vec<[u32; 3]>,
    materials: &mut Vec<MaterialId>,
    corner: Vec3,
    edge_u: Vec3,
    edge_v: Vec3,
    material: MaterialId,
) {
    let b = positions.len() as u32;
    positions.extend_from_slice(&[
        corner,
        corner + edge_u,
        corner + edge_u + edge_v,
        corner + edge_v,
    ]);
    indices.push([b, b + 1, b + 2]);
    indices.push([b, b + 2, b + 3]);
    materials.extend_from_slice(&[material, material]);
}

/// An open-fronted box `[min, max]` with inward-facing walls: floor,
/// ceiling, back (−Z), left (−X), right (+X); one material per wall.
fn open_box(name: &str, min: Vec3, max: Vec3, walls: [MaterialId; 5]) -> Mesh {
    let d = max - min;
    let (mut p, mut i, mut m) = (Vec::new(), Vec::new(), Vec::new());
    let [floor, ceiling, back, left, right] = walls;
    // floor (y = min), normal +Y
    push_quad(
        &mut p,
        &mut i,
        &mut m,
        Vec3::new(min.x, min.y, max.z),
        Vec3::X * d.x,
        Vec3::NEG_Z * d.z,
        floor,
    );
    // ceiling (y = max), normal −Y
    push_quad(
        &mut p,
        &mut i,
        &mut m,
        Vec3::new(min.x, max.y, min.z),
        Vec3::X * d.x,
        Vec3::Z * d.z,
        ceiling,
    );
    // back (z = min), normal +Z
    push_quad(
        &mut p,
        &mut i,
        &mut m,
        min,
        Vec3::X * d.x,
        Vec3::Y * d.y,
        back,
    );
    // left (x = min), normal +X
    push_quad(
        &mut p,
        &mut i,
        &mut m,
        Vec3::new(min.x, min.y, max.z),
        Vec3::NEG_Z * d.z,
        Vec3::Y * d.y,
        left,
    );
    // right (x = max), normal −X
    push_quad(
        &mut p,
        &mut i,
        &mut m,
        Vec3::new(max.x, min.y, min.z),
        Vec3::Z * d.z,
        Vec3::Y * d.y,
        right,
    );
    Mesh {
        materials: MeshMaterials::PerTriangle(m.into()),
        ..Mesh::new(name, p, i, 0)
    }
}

/// The embedded default scene: a Cornell-style box `[-1, 1]³` (red left
/// wall, green right wall, open front), a mirror sphere and a glass sphere
/// on the floor, lit by a quad area light under the ceiling. 512×512, 16
/// samples per pixel, depth 6. Effects: soft shadows, reflection,
/// refraction, anti-aliasing.
pub fn cornell_box() -> Scene {
    let materials = vec![
        Material::diffuse("white", Vec3::splat(0.73)),
        Material::diffuse("red", Vec3::new(0.65, 0.05, 0.05)),
        Material::diffuse("green", Vec3::new(0.12, 0.45, 0.15)),
        Material::mirror("mirror", Vec3::splat(0.95)),
        Material::glass("glass", 1.5),
    ];
    let room = open_box(
        "cornell_room",
        Vec3::splat(-1.0),
        Vec3::splat(1.0),
        [0, 0, 0, 1, 2],
    );
    let spheres = vec![
        Sphere::new(Vec3::new(-0.45, -0.6, -0.35), 0.4, 3),
        Sphere::new(Vec3::new(0.45, -0.6, 0.3), 0.4, 4),
    ];
    Scene {
        meshes: vec![room],
        spheres,
        materials,
        lights: vec![Light::Quad {
            corner: Vec3::new(-0.25, 0.98, -0.25),
            edge_u: Vec3::new(0.5, 0.0, 0.0),
            edge_v: Vec3::new(0.0, 0.0, 0.5),
            color: Vec3::new(1.0, 0.9, 0.8),
            intensity: 15.0,
        }],
        camera: Camera::look_at(Vec3::new(0.0, 0.0, 3.9), Vec3::ZERO, Vec3::Y, 40.0),
        settings: RenderSettings {
            width: 512,
            height: 512,
            spp: 16,
            max_depth: 6,
            ..RenderSettings::default()
        },
        ambient: Vec3::ZERO,
        animation: None,
    }
}

/// Kolodzey's (2014) dynamic scene (chapter 7.2): `model` in metal, scaled to fit
/// a unit sphere and standing on the floor, inside a room with mirrored
/// walls, circled by a ring of `n_spheres` spheres (alternately glass and
/// coloured) that orbit it at 45°/s about the vertical axis. Render frame
/// `k` at time `k / fps` (`triangles_world(t)`, `spheres_at(t)`); the
/// shutter is `[0, 0]`, so there is no motion blur unless the caller opens
/// it. A glass-model variant (the thesis' Fig. 7.3) is one material away:
/// material 1 is "glass". `scenes/dynamic_demo.toml` is this scene as a
/// file, with an `[animation]` and icosphere meshes for the ring.
pub fn dynamic_ring(model: Mesh, n_spheres: u32) -> Result<Scene, SceneError> {
    if u64::from(n_spheres) > MAX_SPHERES {
        return Err(too_large(
            "sphere",
            u64::from(n_spheres),
            MAX_SPHERES,
            "dynamic_ring",
        ));
    }
    let materials = vec![
        Material {
            diffuse: Vec3::new(0.1, 0.08, 0.05),
            specular: Vec3::splat(0.6),
            shininess: 80.0,
            mirror: Vec3::new(0.85, 0.7, 0.45),
            ..Material::diffuse("metal", Vec3::ZERO)
        },
        Material::glass("glass", 1.5),
        Material {
            diffuse: Vec3::splat(0.25),
            mirror: Vec3::splat(0.6),
            ..Material::diffuse("room_mirror", Vec3::ZERO)
        },
        Material::diffuse("floor", Vec3::new(0.6, 0.6, 0.55)),
        Material {
            specular: Vec3::splat(0.5),
            shininess: 40.0,
            ..Material::diffuse("sphere_red", Vec3::new(0.8, 0.15, 0.1))
        },
    ];
    let room = open_box(
        "mirror_room",
        Vec3::new(-5.0, 0.0, -5.0),
        Vec3::new(5.0, 6.0, 5.0),
        [3, 2, 2, 2, 2],
    );
    let mut model = model;
    let ob = model.object_bounds();
    if ob.is_empty() {
        return Err(SceneError::Empty {
            origin: Origin::key("dynamic_ring.model"),
            detail: " (the model has no triangles)".to_owned(),
        });
    }
    let radius = (ob.diagonal() * 0.5).max(f32::MIN_POSITIVE);
    let s = 1.0 / radius;
    let c = ob.center();
    model.transform = Transform {
        translate: Vec3::new(-c.x * s, -ob.min.y * s, -c.z * s),
        rotate: Vec3::ZERO,
        scale: Vec3::splat(s),
    };
    model.materials = MeshMaterials::Single(0);
    model.motion = Motion::STATIC;
    let orbit = Orbit {
        center: Vec3::ZERO,
        axis: Vec3::Y,
        degrees_per_second: 45.0,
    };
    let spheres = (0..n_spheres)
        .map(|k| {
            let a = (k as f32 / n_spheres as f32) * std::f32::consts::TAU;
            Sphere {
                center: Vec3::new(1.8 * a.cos(), 0.6, 1.8 * a.sin()),
                radius: 0.25,
                material: if k % 2 == 0 { 1 } else { 4 },
                motion: Motion {
                    velocity: Vec3::ZERO,
                    orbit: Some(orbit),
                },
            }
        })
        .collect();
    Ok(Scene {
        meshes: vec![room, model],
        spheres,
        materials,
        lights: vec![
            Light::Point {
                position: Vec3::new(2.0, 5.0, 3.0),
                color: Vec3::ONE,
                intensity: 30.0,
            },
            Light::Point {
                position: Vec3::new(-3.0, 4.0, -1.0),
                color: Vec3::new(0.6, 0.7, 1.0),
                intensity: 15.0,
            },
        ],
        camera: Camera::look_at(
            Vec3::new(0.0, 2.2, 5.5),
            Vec3::new(0.0, 0.7, 0.0),
            Vec3::Y,
            45.0,
        ),
        settings: RenderSettings {
            width: 1024,
            height: 768,
            spp: 1,
            max_depth: 5,
            ..RenderSettings::default()
        },
        ambient: Vec3::splat(0.05),
        animation: None,
    })
}
