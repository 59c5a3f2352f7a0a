//! A scene prepared to render as two levels ([`TwoLevelScene`]): what shading reads in place
//! of the flat primitives. The level primitives are every bottom level's triangles then its
//! spheres, bottom level after bottom level; a hit names its instance and the primitive in
//! that instance's bottom level, and the instance's [`Placement`] says where its bottom
//! level's primitives start and how it is placed. Repeated and moving meshes are stored once,
//! in object space; the rest (meshes named once, spheres) in the world, as its identity
//! instance places it.

use glam::{Affine3A, Vec3};

use crate::accel::instances::{world_to_object, Instance};
use crate::scene::{MeshMaterials, Scene};
use crate::trace::instanced::{TwoLevelScene, REST};

use super::types::Placement;

/// Where one bottom level's primitives lie among the level primitives.
#[derive(Clone, Copy, Debug)]
struct Span {
    first: u32,
    triangles: u32,
    first_sphere: u32,
}

/// The shading data of a scene as two levels.
pub struct RenderLevels {
    /// The structures' scene: bottom levels and instances.
    pub scene: TwoLevelScene,
    /// Per level primitive: its three vertices, 9 floats, in its bottom level's space
    /// (spheres: zeros).
    pub verts: Vec<f32>,
    /// The level spheres: centre and radius, in their bottom level's space.
    pub spheres: Vec<[f32; 4]>,
    /// Per instance, in the top level's order.
    pub placements: Vec<Placement>,
    /// Per bottom level, where its primitives lie among the level primitives.
    spans: Vec<Span>,
}

/// The instance's material where it has one (`u32::MAX`: each primitive's).
const PER_PRIMITIVE: u32 = u32::MAX;

impl RenderLevels {
    /// `two` (made of `scene` at `time`) with its shading data; and per level primitive its
    /// material and its shading normals (9 floats, zeros where the mesh has none), what the
    /// flat scene's `prim_material` and `tri_normals` hold per primitive.
    pub fn new(scene: &Scene, two: TwoLevelScene, time: f32) -> (Self, Vec<u32>, Vec<f32>) {
        let (mut verts, mut normals, mut materials) = (Vec::new(), Vec::new(), Vec::new());
        let mut spheres = Vec::new();
        let mut spans = Vec::with_capacity(two.bottoms.len());
        let world_spheres = scene.spheres_at(time);
        let n_tris = scene.triangle_count() as u32;
        for (b, _) in two.bottoms.iter().enumerate() {
            let span = Span {
                first: materials.len() as u32,
                triangles: 0,
                first_sphere: spheres.len() as u32,
            };
            let instance = two.instances.iter().find(|i| i.bottom == b as u64);
            let triangles = match instance.map(Instance::custom_index) {
                // A repeated or moving mesh, in object space.
                Some(k) if k != REST => {
                    let mesh = &scene.meshes[k as usize];
                    let place = Affine3A::IDENTITY;
                    (0..mesh.indices.len())
                        .map(|t| corners(mesh, t, &place, &mut verts, &mut normals))
                        .count();
                    match &mesh.materials {
                        MeshMaterials::Single(id) => {
                            materials.extend(std::iter::repeat_n(*id, mesh.indices.len()))
                        }
                        MeshMaterials::PerTriangle(ids) => materials.extend_from_slice(ids),
                    }
                    mesh.indices.len()
                }
                // The rest: its triangles in the world, then its spheres.
                _ => {
                    let mut n = 0;
                    for &id in &two.rest_ids {
                        if id >= n_tris {
                            let s = &world_spheres[(id - n_tris) as usize];
                            spheres.push(s.center.extend(s.radius).to_array());
                            verts.extend([0.0; 9]);
                            normals.extend([0.0; 9]);
                            materials.push(s.material);
                            continue;
                        }
                        let k = two.mesh_first.partition_point(|&f| f <= id) - 1;
                        let (mesh, t) = (&scene.meshes[k], (id - two.mesh_first[k]) as usize);
                        corners(mesh, t, &mesh.world_matrix(time), &mut verts, &mut normals);
                        materials.push(match &mesh.materials {
                            MeshMaterials::Single(m) => *m,
                            MeshMaterials::PerTriangle(ids) => ids[t],
                        });
                        n += 1;
                    }
                    n
                }
            };
            spans.push(Span {
                triangles: triangles as u32,
                ..span
            });
        }
        let placements = placements(scene, &two.instances, &spans);
        let levels = Self {
            scene: two,
            verts,
            spheres,
            placements,
            spans,
        };
        (levels, materials, normals)
    }

    /// The instances and placements of `scene` (this one's scene, its meshes moved) at
    /// `time`: what an animation's later frame changes. The bottom levels and the rest stay.
    pub fn move_to(&mut self, scene: &Scene, time: f32) {
        for inst in &mut self.scene.instances {
            if inst.custom_index() != REST {
                let m = scene.meshes[inst.custom_index() as usize].world_matrix(time);
                inst.transform = Instance::rows_of(&m);
            }
        }
        self.placements = placements(scene, &self.scene.instances, &self.spans);
    }
}

/// Appends triangle `t` of `mesh` placed by `place`: its vertices, and its shading normals
/// (moved by the inverse transpose, unit; zeros where the mesh has none).
fn corners(
    mesh: &crate::scene::Mesh,
    t: usize,
    place: &Affine3A,
    verts: &mut Vec<f32>,
    normals: &mut Vec<f32>,
) {
    let normal_m = place.matrix3.inverse().transpose();
    for i in mesh.indices[t] {
        let p = place.transform_point3(mesh.positions[i as usize]);
        verts.extend(p.to_array());
        let n = match mesh.normals.get(i as usize) {
            Some(&n) => (normal_m * n).normalize_or_zero(),
            None => Vec3::ZERO,
        };
        normals.extend(n.to_array());
    }
}

/// Per instance its placement: its bottom level's span, its transforms, its material (a mesh
/// with one material: the instance's own mesh's, so copies may differ).
fn placements(scene: &Scene, instances: &[Instance], spans: &[Span]) -> Vec<Placement> {
    instances
        .iter()
        .map(|inst| {
            let span = spans[inst.bottom as usize];
            let material = match inst.custom_index() {
                REST => PER_PRIMITIVE,
                k => match &scene.meshes[k as usize].materials {
                    MeshMaterials::Single(id) => *id,
                    MeshMaterials::PerTriangle(_) => PER_PRIMITIVE,
                },
            };
            Placement {
                object_to_world: inst.transform,
                // (a singular transform is never hit: its instance is inactive)
                world_to_object: world_to_object(&inst.transform).unwrap_or_default(),
                info: [span.first, span.triangles, span.first_sphere, material],
            }
        })
        .collect()
}
