//! Writing a [`Scene`] in the TOML format: every field explicit, meshes
//! inline, floats in their shortest form that parses back exactly, so
//! reading the output gives back an equal scene.

use std::collections::HashMap;
use std::fmt::Write as _;

use glam::Vec3;

use super::model::{Light, MaterialId, MeshMaterials, Motion};
use super::toml_locate::push_key;
use super::Scene;

/// Shortest text that parses back to exactly `v` (TOML spelling for
/// non-finite values).
fn num(v: f32) -> String {
    if v.is_nan() {
        "nan".to_owned()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.to_owned()
    } else {
        format!("{v:?}")
    }
}

fn vec(v: Vec3) -> String {
    format!("[{}, {}, {}]", num(v.x), num(v.y), num(v.z))
}

fn string(s: &str) -> String {
    toml::Value::String(s.to_owned()).to_string()
}

fn table_key(k: &str) -> String {
    let mut s = String::new();
    push_key(&mut s, k);
    if s.starts_with('"') {
        string(k)
    } else {
        s
    }
}

fn write_motion(out: &mut String, m: &Motion, table: &str) {
    if m.velocity != Vec3::ZERO {
        let _ = writeln!(out, "velocity = {}", vec(m.velocity));
    }
    if let Some(o) = m.orbit {
        let _ = writeln!(out, "[{table}.orbit]");
        let _ = writeln!(out, "center = {}", vec(o.center));
        let _ = writeln!(out, "axis = {}", vec(o.axis));
        let _ = writeln!(out, "degrees_per_second = {}", num(o.degrees_per_second));
    }
}

/// Serialize a scene to the TOML format. Material names are made unique
/// (empty names become `material<i>`, repeats get `#<n>`).
pub fn scene_to_toml(scene: &Scene) -> String {
    let mut out = String::new();
    let mut names: Vec<String> = Vec::with_capacity(scene.materials.len());
    let mut seen: HashMap<String, usize> = HashMap::new();
    for (i, m) in scene.materials.iter().enumerate() {
        let base = if m.name.is_empty() {
            format!("material{i}")
        } else {
            m.name.clone()
        };
        let mut name = base.clone();
        let mut n = 1;
        while seen.contains_key(&name) {
            n += 1;
            name = format!("{base}#{n}");
        }
        seen.insert(name.clone(), i);
        names.push(name);
    }
    let mat = |id: MaterialId| string(names.get(id as usize).map_or("<invalid>", |s| s.as_str()));

    let _ = writeln!(out, "# vkrt scene (written by Scene::to_toml_string)");
    let _ = writeln!(out, "ambient = {}", vec(scene.ambient));
    let s = &scene.settings;
    let _ = writeln!(out, "\n[settings]");
    let _ = writeln!(
        out,
        "width = {}\nheight = {}\nspp = {}\nmax_depth = {}",
        s.width, s.height, s.spp, s.max_depth
    );
    let _ = writeln!(
        out,
        "background = {}\nantialias = {}",
        vec(s.background),
        s.antialias
    );
    let _ = writeln!(out, "\n[settings.ao]");
    let _ = writeln!(
        out,
        "enabled = {}\nradius = {}\nsamples = {}",
        s.ao.enabled,
        num(s.ao.radius),
        s.ao.samples
    );
    let c = &scene.camera;
    let _ = writeln!(out, "\n[camera]");
    let _ = writeln!(
        out,
        "position = {}\nlook_at = {}\nup = {}",
        vec(c.position),
        vec(c.look_at),
        vec(c.up)
    );
    let _ = writeln!(
        out,
        "fov = {}\naperture = {}\nfocus_distance = {}",
        num(c.fov),
        num(c.aperture_radius),
        num(c.focus_distance)
    );
    let _ = writeln!(
        out,
        "shutter = [{}, {}]",
        num(c.shutter_open),
        num(c.shutter_close)
    );

    for (m, name) in scene.materials.iter().zip(&names) {
        let _ = writeln!(out, "\n[materials.{}]", table_key(name));
        let _ = writeln!(
            out,
            "diffuse = {}\nspecular = {}\nshininess = {}",
            vec(m.diffuse),
            vec(m.specular),
            num(m.shininess)
        );
        let _ = writeln!(
            out,
            "mirror = {}\nroughness = {}",
            vec(m.mirror),
            num(m.roughness)
        );
        let _ = writeln!(
            out,
            "transmission = {}\nior = {}\nfresnel = {}",
            num(m.transmission),
            num(m.ior),
            m.fresnel
        );
        let _ = writeln!(out, "emission = {}", vec(m.emission));
    }

    for l in &scene.lights {
        let _ = writeln!(out, "\n[[lights]]\ntype = \"{}\"", l.kind());
        match *l {
            Light::Point { position, .. } => {
                let _ = writeln!(out, "position = {}", vec(position));
            }
            Light::Sphere { center, radius, .. } => {
                let _ = writeln!(out, "center = {}\nradius = {}", vec(center), num(radius));
            }
            Light::Quad {
                corner,
                edge_u,
                edge_v,
                ..
            } => {
                let _ = writeln!(
                    out,
                    "corner = {}\nedge_u = {}\nedge_v = {}",
                    vec(corner),
                    vec(edge_u),
                    vec(edge_v)
                );
            }
            Light::Directional { direction, .. } => {
                let _ = writeln!(out, "direction = {}", vec(direction));
            }
        }
        let (color, intensity) = match *l {
            Light::Point {
                color, intensity, ..
            }
            | Light::Sphere {
                color, intensity, ..
            }
            | Light::Quad {
                color, intensity, ..
            }
            | Light::Directional {
                color, intensity, ..
            } => (color, intensity),
        };
        let _ = writeln!(
            out,
            "color = {}\nintensity = {}",
            vec(color),
            num(intensity)
        );
    }

    for sp in &scene.spheres {
        let _ = writeln!(out, "\n[[spheres]]");
        let _ = writeln!(
            out,
            "center = {}\nradius = {}\nmaterial = {}",
            vec(sp.center),
            num(sp.radius),
            mat(sp.material)
        );
        write_motion(&mut out, &sp.motion, "spheres");
    }

    for mesh in &scene.meshes {
        let _ = writeln!(out, "\n[[meshes]]");
        let _ = writeln!(out, "name = {}", string(&mesh.name));
        let t = &mesh.transform;
        let _ = writeln!(
            out,
            "translate = {}\nrotate = {}\nscale = {}",
            vec(t.translate),
            vec(t.rotate),
            vec(t.scale)
        );
        match &mesh.materials {
            MeshMaterials::Single(id) => {
                let _ = writeln!(out, "material = {}", mat(*id));
            }
            MeshMaterials::PerTriangle(ids) => {
                out.push_str("triangle_materials = [\n");
                for id in ids {
                    let _ = writeln!(out, "  {},", mat(*id));
                }
                out.push_str("]\n");
            }
        }
        out.push_str("positions = [\n");
        for p in &mesh.positions {
            let _ = writeln!(out, "  {},", vec(*p));
        }
        out.push_str("]\n");
        if !mesh.normals.is_empty() {
            out.push_str("normals = [\n");
            for n in &mesh.normals {
                let _ = writeln!(out, "  {},", vec(*n));
            }
            out.push_str("]\n");
        }
        out.push_str("indices = [\n");
        for [a, b, c] in &mesh.indices {
            let _ = writeln!(out, "  [{a}, {b}, {c}],");
        }
        out.push_str("]\n");
        write_motion(&mut out, &mesh.motion, "meshes");
    }
    out
}
