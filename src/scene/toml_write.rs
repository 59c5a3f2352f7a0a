//! Writing a [`Scene`] in the TOML format: the scene becomes the same
//! `*Def` types the reader uses, every field explicit and meshes inline,
//! and `toml_edit` serializes them. Floats are written in their shortest
//! form that parses back exactly, so reading the output gives back an
//! equal scene.

use std::collections::HashSet;

use glam::Vec3;
use toml_edit::visit_mut::{self, VisitMut};
use toml_edit::{Array, Formatted, Item, Table, Value};

use super::model::{Light, MaterialId, Mesh, MeshMaterials, Motion, Sphere};
use super::toml_anim::{animation_def, keyframe_defs};
use super::toml_defs::{
    AoDef, CameraDef, LightDef, LightKind, MaterialDef, MeshDef, OrbitDef, Ordered, SceneDef,
    SettingsDef, SphereDef, Vec3OrScalar,
};
use super::Scene;

/// Serialize a scene to the TOML format. Material names are made unique
/// (empty names become `material<i>`, repeats get `#<n>`).
pub fn scene_to_toml(scene: &Scene) -> String {
    let names = unique_names(scene);
    let (s, c) = (&scene.settings, &scene.camera);
    let def = SceneDef {
        ambient: Some(scene.ambient.to_array()),
        settings: Some(SettingsDef {
            width: Some(s.width),
            height: Some(s.height),
            spp: Some(s.spp),
            max_depth: Some(s.max_depth),
            background: Some(s.background.to_array()),
            antialias: Some(s.antialias),
            ao: Some(AoDef {
                enabled: Some(s.ao.enabled),
                radius: Some(s.ao.radius),
                samples: Some(s.ao.samples),
            }),
        }),
        camera: Some(CameraDef {
            position: c.position.to_array(),
            look_at: c.look_at.to_array(),
            up: Some(c.up.to_array()),
            fov: Some(c.fov),
            aperture: Some(c.aperture_radius),
            focus_distance: Some(c.focus_distance),
            shutter: Some([c.shutter_open, c.shutter_close]),
        }),
        animation: scene.animation.as_ref().map(animation_def),
        materials: Ordered(
            scene
                .materials
                .iter()
                .zip(&names)
                .map(|(m, name)| {
                    let def = MaterialDef {
                        diffuse: Some(m.diffuse.to_array()),
                        specular: Some(Vec3OrScalar(m.specular.to_array())),
                        shininess: Some(m.shininess),
                        mirror: Some(Vec3OrScalar(m.mirror.to_array())),
                        roughness: Some(m.roughness),
                        transmission: Some(m.transmission),
                        ior: Some(m.ior),
                        fresnel: Some(m.fresnel),
                        emission: Some(m.emission.to_array()),
                    };
                    (name.clone(), def)
                })
                .collect(),
        ),
        lights: scene.lights.iter().map(light_def).collect(),
        spheres: scene
            .spheres
            .iter()
            .map(|sp| sphere_def(sp, &names))
            .collect(),
        meshes: scene.meshes.iter().map(|m| mesh_def(m, &names)).collect(),
    };
    let mut doc = toml_edit::ser::to_document(&def).expect("a scene always serializes");
    Tidy::default().visit_document_mut(&mut doc);
    format!("# vkrt scene (written by Scene::to_toml_string)\n{doc}")
}

fn unique_names(scene: &Scene) -> Vec<String> {
    let mut seen = HashSet::new();
    let mut names = Vec::with_capacity(scene.materials.len());
    for (i, m) in scene.materials.iter().enumerate() {
        let base = if m.name.is_empty() {
            format!("material{i}")
        } else {
            m.name.clone()
        };
        let mut name = base.clone();
        let mut n = 1;
        while seen.contains(&name) {
            n += 1;
            name = format!("{base}#{n}");
        }
        seen.insert(name.clone());
        names.push(name);
    }
    names
}

fn material_name(names: &[String], id: MaterialId) -> String {
    names
        .get(id as usize)
        .map_or_else(|| "<invalid>".to_owned(), String::clone)
}

fn light_def(l: &Light) -> LightDef {
    let (color, intensity) = l.color_intensity();
    let mut def = LightDef {
        kind: LightKind::Point,
        position: None,
        center: None,
        radius: None,
        corner: None,
        edge_u: None,
        edge_v: None,
        direction: None,
        color: Some(color.to_array()),
        intensity: Some(intensity),
    };
    match *l {
        Light::Point { position, .. } => def.position = Some(position.to_array()),
        Light::Sphere { center, radius, .. } => {
            def.kind = LightKind::Sphere;
            def.center = Some(center.to_array());
            def.radius = Some(radius);
        }
        Light::Quad {
            corner,
            edge_u,
            edge_v,
            ..
        } => {
            def.kind = LightKind::Quad;
            def.corner = Some(corner.to_array());
            def.edge_u = Some(edge_u.to_array());
            def.edge_v = Some(edge_v.to_array());
        }
        Light::Directional { direction, .. } => {
            def.kind = LightKind::Directional;
            def.direction = Some(direction.to_array());
        }
    }
    def
}

/// `velocity` and `orbit`, each only when the object moves that way.
fn motion_defs(m: &Motion) -> (Option<[f32; 3]>, Option<OrbitDef>) {
    let velocity = (m.velocity != Vec3::ZERO).then(|| m.velocity.to_array());
    let orbit = m.orbit.map(|o| OrbitDef {
        center: Some(o.center.to_array()),
        axis: Some(o.axis.to_array()),
        degrees_per_second: o.degrees_per_second,
    });
    (velocity, orbit)
}

fn sphere_def(sp: &Sphere, names: &[String]) -> SphereDef {
    let (velocity, orbit) = motion_defs(&sp.motion);
    SphereDef {
        center: sp.center.to_array(),
        radius: sp.radius,
        material: Some(material_name(names, sp.material)),
        velocity,
        orbit,
    }
}

fn mesh_def(mesh: &Mesh, names: &[String]) -> MeshDef {
    let (velocity, orbit) = motion_defs(&mesh.motion);
    let t = &mesh.transform;
    let (material, triangle_materials) = match &mesh.materials {
        MeshMaterials::Single(id) => (Some(material_name(names, *id)), None),
        MeshMaterials::PerTriangle(ids) => (
            None,
            Some(ids.iter().map(|&id| material_name(names, id)).collect()),
        ),
    };
    let arrays = |v: &[Vec3]| v.iter().map(|p| p.to_array()).collect();
    MeshDef {
        name: Some(mesh.name.clone()),
        positions: Some(arrays(&mesh.positions)),
        normals: (!mesh.normals.is_empty()).then(|| arrays(&mesh.normals)),
        indices: Some(mesh.indices.to_vec()),
        material,
        triangle_materials,
        translate: Some(t.translate.to_array()),
        rotate: Some(t.rotate.to_array()),
        scale: Some(Vec3OrScalar(t.scale.to_array())),
        velocity,
        orbit,
        keyframes: keyframe_defs(&mesh.keyframes),
        mask: (mesh.instance.mask != 0xff).then_some(i64::from(mesh.instance.mask)),
        custom_index: mesh.instance.custom_index.map(i64::from),
        sbt_offset: (mesh.instance.sbt_offset != 0).then_some(i64::from(mesh.instance.sbt_offset)),
        flags: (mesh.instance.flags != 0).then(|| mesh.instance.flag_names()),
        opaque: (!mesh.instance.opaque).then_some(false),
        ..MeshDef::default()
    }
}

/// `[table]` and `[[array]]` sections instead of inline tables (as `toml`'s
/// own writer does), shortest floats, and one line per item of long arrays.
#[derive(Default)]
struct Tidy {
    in_value: bool,
}

impl VisitMut for Tidy {
    fn visit_item_mut(&mut self, node: &mut Item) {
        let parent_in_value = self.in_value;
        if !parent_in_value {
            let item = std::mem::take(node);
            let item = item.into_table().map(Item::Table).unwrap_or_else(|i| i);
            *node = item
                .into_array_of_tables()
                .map(Item::ArrayOfTables)
                .unwrap_or_else(|i| i);
            self.in_value = node.is_value();
        }
        visit_mut::visit_item_mut(self, node);
        self.in_value = parent_in_value;
    }

    fn visit_table_mut(&mut self, node: &mut Table) {
        // No header for tables that hold only tables (`[materials]`).
        node.set_implicit(true);
        visit_mut::visit_table_mut(self, node);
    }

    fn visit_float_mut(&mut self, node: &mut Formatted<f64>) {
        // Every float here was an `f32`; serde widened it to `f64` (0.1 →
        // 0.10000000149011612). The shortest `f32` text parses back to the
        // same `f32`.
        let v = *node.value() as f32;
        if v.is_finite() {
            *node = Formatted::new(format!("{v:?}").parse().unwrap_or(f64::from(v)));
        }
    }

    fn visit_array_mut(&mut self, node: &mut Array) {
        visit_mut::visit_array_mut(self, node);
        // Vectors stay inline; vertex, index and material lists get a line
        // per item.
        if node.len() > 3 || node.iter().any(Value::is_array) {
            for v in node.iter_mut() {
                v.decor_mut().set_prefix("\n  ");
                v.decor_mut().set_suffix("");
            }
            node.set_trailing_comma(true);
            node.set_trailing("\n");
        }
    }
}
