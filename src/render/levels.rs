//! A scene prepared to render as two levels ([`TwoLevelScene`]): what shading reads in place
//! of the flat primitives. The level primitives are every bottom level's triangles then its
//! spheres, bottom level after bottom level; a hit names its instance and the primitive in
//! that instance's bottom level, and the instance's [`Placement`] says where its bottom
//! level's primitives start and how it is placed. Repeated and moving meshes are stored once,
//! in object space; the rest (meshes named once, spheres) in the world, as its identity
//! instance places it.

use glam::{Mat3A, Vec3};

use crate::accel::instances::{world_to_object, Instance};
use crate::scene::{Mesh, MeshMaterials, Scene};
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
        let (mut verts, mut spheres) = (Vec::new(), Vec::new());
        let (mut normals, mut materials) = (Vec::new(), Vec::new());
        let mut spans = Vec::with_capacity(two.bottoms.len());
        let world_spheres = scene.spheres_at(time);
        let n_tris = scene.triangle_count() as u32;
        for (b, g) in two.bottoms.iter().enumerate() {
            spans.push(Span {
                first: materials.len() as u32,
                triangles: g.triangle_count() as u32,
                first_sphere: spheres.len() as u32,
            });
            // The bottom level's own primitives, as it was built over them.
            verts.extend_from_slice(&g.tri_verts);
            verts.extend(std::iter::repeat_n(0.0, 9 * g.spheres.len()));
            spheres.extend_from_slice(&g.spheres);
            let mut triangle = |mesh: &Mesh, t: usize, normal_m: &Mat3A| {
                let n = mesh.corner_normals(t, normal_m).unwrap_or([Vec3::ZERO; 3]);
                normals.extend(n.iter().flat_map(|v| v.to_array()));
                materials.push(match &mesh.materials {
                    MeshMaterials::Single(m) => *m,
                    MeshMaterials::PerTriangle(ids) => ids[t],
                });
            };
            let instance = two.instances.iter().find(|i| i.bottom == b as u64);
            match instance.map(Instance::custom_index) {
                // A repeated or moving mesh, in object space.
                Some(k) if k != REST => {
                    let mesh = &scene.meshes[k as usize];
                    for t in 0..mesh.indices.len() {
                        triangle(mesh, t, &Mat3A::IDENTITY);
                    }
                }
                // The rest: its triangles in the world (mesh after mesh), then its spheres.
                _ => {
                    let mut placed: Option<(usize, Mat3A)> = None;
                    for &id in two.rest_ids.iter().filter(|&&id| id < n_tris) {
                        let k = two.mesh_first.partition_point(|&f| f <= id) - 1;
                        let mesh = &scene.meshes[k];
                        let normal_m = match placed {
                            Some((at, m)) if at == k => m,
                            _ => {
                                let m = mesh.world_matrix(time).matrix3.inverse().transpose();
                                placed = Some((k, m));
                                m
                            }
                        };
                        triangle(mesh, (id - two.mesh_first[k]) as usize, &normal_m);
                    }
                    for &id in two.rest_ids.iter().filter(|&&id| id >= n_tris) {
                        normals.extend([0.0; 9]);
                        materials.push(world_spheres[(id - n_tris) as usize].material);
                    }
                }
            }
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
