//! The TOML scene format (documented in `docs/scene-format.md`).
//!
//! Parsing is three steps, each with its own kind of error:
//!
//! 1. `toml` + serde into the `*Def` structs below. Every struct has
//!    `deny_unknown_fields`, so a misspelt key is an error; `toml` gives the
//!    span; `toml_locate` (spans from `toml_edit`) names the key there.
//! 2. Definitions to model: material names resolved, mesh files loaded
//!    (OBJ, relative to the scene file; a missing one replaced by its
//!    `fallback` entry), generators run (their size checked first),
//!    `[animation]` and keyframes read (`toml_anim`). Errors carry TOML key
//!    paths.
//! 3. [`validate`](super::validate::validate) on the model. Its key paths
//!    are the TOML ones except for materials (`materials[3]` →
//!    `materials.glass`), which are mapped back here.
//!
//! Key paths become `file:line:column` through the locator, so every
//! message reads like
//!
//! ```text
//! scenes/glass.toml:14:1: `spheres[1].radius`: -1 is out of range: must be > 0
//! ```
//!
//! [`scene_to_toml`] writes the format back (meshes inline, floats in their
//! shortest round-tripping form), so TOML → Scene → TOML → Scene is exact.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::Vec3;

use super::error::{Origin, SceneError};
use super::files::FileSource;
use super::gen;
use super::instance_keys::InstanceKeys;
use super::limits::Limits;
use super::material::Material;
use super::model::{
    AmbientOcclusion, Camera, Light, MaterialId, Mesh, MeshMaterials, Motion, Orbit,
    RenderSettings, Sphere, Transform,
};
use super::obj;
use super::toml_anim::{animation_from_def, keyframes_from_defs};
use super::toml_defs::{
    GenKind, LightDef, LightKind, MaterialDef, MeshDef, OrbitDef, SceneDef, SettingsDef,
};
use super::toml_locate::{line_col, push_key, Locator};
use super::validate;
use super::{LoadedScene, Scene};

pub use super::toml_write::scene_to_toml;

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

fn motion_of(velocity: Option<[f32; 3]>, orbit: Option<&OrbitDef>) -> Motion {
    Motion {
        velocity: velocity.map_or(Vec3::ZERO, v3),
        orbit: orbit.map(|o| Orbit {
            center: o.center.map_or(Vec3::ZERO, v3),
            axis: o.axis.map_or(Vec3::Y, v3),
            degrees_per_second: o.degrees_per_second,
        }),
    }
}

/// Parse and validate TOML scene text. `path` names the text in messages;
/// meshes resolve against `base_dir` through `files`.
pub fn parse_toml_scene(
    text: &str,
    path: &Path,
    base_dir: &Path,
    files: &dyn FileSource,
    limits: &Limits,
) -> Result<LoadedScene, SceneError> {
    let def: SceneDef = toml::from_str(text).map_err(|e| toml_error(&e, text, path))?;
    let material_names: Vec<String> = def.materials.0.iter().map(|(k, _)| k.clone()).collect();
    let build = Builder {
        base_dir,
        files,
        limits,
        scene_path: path,
    };
    let (mut scene, mut warnings, fallbacks) = build
        .scene(def)
        .map_err(|e| locate(e, text, path, &material_names))?;
    let more = validate::validate(&mut scene, limits).map_err(|mut e| {
        // Validation names meshes by index; a mesh built from its fallback
        // is written under `meshes[i].fallback`.
        if let Some(o) = e.origin_mut() {
            o.key = o.key.take().map(|k| fallback_key(k, &fallbacks));
        }
        locate(e, text, path, &material_names)
    })?;
    warnings.extend(more.into_iter().map(|w| format!("{}: {w}", path.display())));
    Ok(LoadedScene { scene, warnings })
}

/// A `toml` error as a [`SceneError::Syntax`] with file, line, column and,
/// when the text scans, the key at the error.
fn toml_error(e: &toml::de::Error, text: &str, path: &Path) -> SceneError {
    let mut origin = Origin::file(path);
    if let Some(span) = e.span() {
        let (line, col) = line_col(text, span.start);
        origin.line = Some(line);
        origin.column = Some(col);
        origin.key = Locator::new(text).path_at(span.start).map(str::to_owned);
    }
    SceneError::syntax(origin, e.message().trim_end())
}

/// Turn a key-path-only error into one with file, line and column.
fn locate(mut err: SceneError, text: &str, path: &Path, material_names: &[String]) -> SceneError {
    if let Some(origin) = err.origin_mut() {
        if origin.file.is_some() {
            return err; // already located (e.g. in an OBJ file)
        }
        origin.file = Some(path.to_owned());
        if let Some(key) = origin.key.take() {
            let key = material_key(&key, material_names);
            if let Some((offset, _)) = Locator::new(text).find(&key) {
                let (line, col) = line_col(text, offset);
                origin.line = Some(line);
                origin.column = Some(col);
            }
            origin.key = Some(key);
        }
    }
    err
}

/// `meshes[i].x` → `meshes[i].fallback.x` when mesh `i` was built from its
/// fallback (`fallbacks` holds `(i, "meshes[i].fallback")`, nested as
/// deep as the fallbacks used).
fn fallback_key(key: String, fallbacks: &[(usize, String)]) -> String {
    for (i, entry) in fallbacks {
        let top = format!("meshes[{i}]");
        if let Some(rest) = key.strip_prefix(&top) {
            if rest.is_empty() || rest.starts_with(['.', '[']) {
                return format!("{entry}{rest}");
            }
        }
    }
    key
}

/// `materials[i].x` → `materials.<name>.x` for materials defined in the file.
fn material_key(key: &str, names: &[String]) -> String {
    let Some(rest) = key.strip_prefix("materials[") else {
        return key.to_owned();
    };
    let Some(close) = rest.find(']') else {
        return key.to_owned();
    };
    match rest[..close]
        .parse::<usize>()
        .ok()
        .and_then(|i| names.get(i))
    {
        Some(name) => {
            let mut k = "materials".to_owned();
            push_key(&mut k, name);
            k.push_str(&rest[close + 1..]);
            k
        }
        None => key.to_owned(),
    }
}

struct Builder<'a> {
    base_dir: &'a Path,
    files: &'a dyn FileSource,
    limits: &'a Limits,
    scene_path: &'a Path,
}

fn key(k: String) -> Origin {
    Origin::key(k)
}

/// A scene as built, its warnings, and which meshes came from a fallback
/// (index, key of the entry used).
type Built = (Scene, Vec<String>, Vec<(usize, String)>);

impl Builder<'_> {
    fn scene(&self, def: SceneDef) -> Result<Built, SceneError> {
        let mut warnings = Vec::new();
        let mut materials: Vec<Material> = def
            .materials
            .0
            .iter()
            .map(|(name, m)| material_from_def(name, m))
            .collect();
        let names: HashMap<&str, MaterialId> = def
            .materials
            .0
            .iter()
            .enumerate()
            .map(|(i, (n, _))| (n.as_str(), i as MaterialId))
            .collect();
        if materials.len() as u64 > self.limits.max_materials {
            return Err(SceneError::TooLarge {
                origin: Origin::key("materials"),
                what: "material",
                count: materials.len() as u64,
                limit: self.limits.max_materials,
            });
        }
        // The implicit default material, added on first use.
        let mut default_id: Option<MaterialId> = None;
        let mut resolve =
            |name: Option<&String>, k: String, materials: &mut Vec<Material>| match name {
                Some(n) => names.get(n.as_str()).copied().ok_or_else(|| {
                    let mut defined: Vec<&str> = names.keys().copied().collect();
                    defined.sort_unstable();
                    let hint = if defined.is_empty() {
                        "; the file defines no [materials]".to_owned()
                    } else if defined.len() <= 12 {
                        format!("; defined: {}", defined.join(", "))
                    } else {
                        format!("; {} materials are defined", defined.len())
                    };
                    SceneError::UnknownName {
                        origin: key(k),
                        kind: "material",
                        name: n.clone(),
                        hint: hint.into(),
                    }
                }),
                None => Ok(*default_id.get_or_insert_with(|| {
                    materials.push(Material::default());
                    (materials.len() - 1) as MaterialId
                })),
            };

        let settings = settings_from_def(def.settings.unwrap_or_default());

        let mut spheres = Vec::with_capacity(def.spheres.len());
        if def.spheres.len() as u64 > self.limits.max_spheres {
            return Err(SceneError::TooLarge {
                origin: Origin::key("spheres"),
                what: "sphere",
                count: def.spheres.len() as u64,
                limit: self.limits.max_spheres,
            });
        }
        for (i, s) in def.spheres.iter().enumerate() {
            let material = resolve(
                s.material.as_ref(),
                format!("spheres[{i}].material"),
                &mut materials,
            )?;
            spheres.push(Sphere {
                center: v3(s.center),
                radius: s.radius,
                material,
                motion: motion_of(s.velocity, s.orbit.as_ref()),
            });
        }

        let mut lights = Vec::with_capacity(def.lights.len());
        for (i, l) in def.lights.iter().enumerate() {
            lights.push(light_from_def(l, i)?);
        }

        let mut meshes = Vec::with_capacity(def.meshes.len());
        let mut obj_cache: HashMap<PathBuf, CachedObj> = HashMap::new();
        let mut generated: HashMap<String, Mesh> = HashMap::new();
        let mut held = HashSet::new();
        let (mut total_triangles, mut instanced_triangles) = (0u64, 0u64);
        let mut fallbacks = Vec::new();
        for (i, m) in def.meshes.iter().enumerate() {
            let top = format!("meshes[{i}]");
            let (m, k) = self.present_entry(m, top.clone(), &mut warnings)?;
            if k != top {
                fallbacks.push((i, k.clone()));
            }
            let sources = [
                m.path.is_some(),
                m.positions.is_some() || m.indices.is_some(),
                m.generate.is_some(),
            ];
            if sources.iter().filter(|s| **s).count() != 1 {
                return Err(SceneError::invalid(
                    key(k),
                    "a mesh needs exactly one of `path`, `positions` + `indices`, or `generate`",
                ));
            }
            let mut mesh = if let Some(rel) = &m.path {
                self.mesh_from_file(rel, &k, m, &mut materials, &mut obj_cache, &mut warnings)?
            } else if m.generate.is_some() {
                // The same generator and parameters again: the same mesh, shared.
                let params = generator_params(m);
                match generated.get(&params) {
                    Some(mesh) => Mesh::clone(mesh),
                    None => {
                        let mesh = self.generated_mesh(m, &k, total_triangles)?;
                        generated.insert(params, mesh.clone());
                        mesh
                    }
                }
            } else {
                inline_mesh(m, &k)?
            };
            // Triangles held: a mesh shared with an earlier entry counts once.
            if held.insert(Arc::as_ptr(&mesh.indices)) {
                total_triangles += mesh.indices.len() as u64;
            }
            instanced_triangles += mesh.indices.len() as u64;
            if instanced_triangles > self.limits.max_instanced_triangles {
                return Err(SceneError::TooLarge {
                    origin: key(k),
                    what: "instanced triangle",
                    count: instanced_triangles,
                    limit: self.limits.max_instanced_triangles,
                });
            }
            if total_triangles > self.limits.max_triangles {
                return Err(SceneError::TooLarge {
                    origin: key(k),
                    what: "triangle",
                    count: total_triangles,
                    limit: self.limits.max_triangles,
                });
            }
            if let Some(name) = &m.name {
                mesh.name = name.clone();
            }
            // Materials: explicit override, per-triangle names, the file's
            // own (OBJ), or the default.
            if let Some(names) = &m.triangle_materials {
                if m.material.is_some() {
                    return Err(SceneError::invalid(
                        key(format!("{k}.triangle_materials")),
                        "give either `material` or `triangle_materials`, not both",
                    ));
                }
                let mut ids = Vec::with_capacity(names.len());
                for (j, n) in names.iter().enumerate() {
                    ids.push(resolve(
                        Some(n),
                        format!("{k}.triangle_materials[{j}]"),
                        &mut materials,
                    )?);
                }
                mesh.materials = MeshMaterials::PerTriangle(ids.into());
            } else if m.material.is_some() || m.path.is_none() {
                let id = resolve(m.material.as_ref(), format!("{k}.material"), &mut materials)?;
                mesh.materials = MeshMaterials::Single(id);
            }
            mesh.transform = Transform {
                translate: m.translate.map_or(Vec3::ZERO, v3),
                rotate: m.rotate.map_or(Vec3::ZERO, v3),
                scale: m.scale.map_or(Vec3::ONE, |s| v3(s.0)),
            };
            mesh.keyframes = keyframes_from_defs(&m.keyframes);
            mesh.motion = motion_of(m.velocity, m.orbit.as_ref());
            mesh.instance = InstanceKeys::from_def(
                &k,
                m.mask,
                m.custom_index,
                m.sbt_offset,
                m.flags.as_deref(),
                m.opaque,
            )?;
            meshes.push(mesh);
        }

        let mut scene = Scene {
            meshes,
            spheres,
            materials,
            lights,
            camera: Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0),
            settings,
            ambient: def.ambient.map_or(Vec3::ZERO, v3),
            animation: def.animation.as_ref().map(animation_from_def).transpose()?,
        };
        match def.camera {
            Some(c) => {
                let position = v3(c.position);
                let look_at = v3(c.look_at);
                let shutter = c.shutter.unwrap_or([0.0, 0.0]);
                scene.camera = Camera {
                    position,
                    look_at,
                    up: c.up.map_or(Vec3::Y, v3),
                    fov: c.fov.unwrap_or(40.0),
                    aperture_radius: c.aperture.unwrap_or(0.0),
                    focus_distance: c.focus_distance.unwrap_or((look_at - position).length()),
                    shutter_open: shutter[0],
                    shutter_close: shutter[1],
                };
            }
            None => {
                scene.frame_camera();
                warnings.push(format!(
                    "{}: no [camera]: using one that frames the scene bounds",
                    self.scene_path.display()
                ));
            }
        }
        Ok((scene, warnings, fallbacks))
    }

    /// The entry that builds mesh `k`: `m` itself or, when its `path` names
    /// a file that does not exist and it has a `fallback`, that fallback
    /// (recursively), with a warning. The fallback replaces the whole
    /// entry: it is read as if it stood in `m`'s place.
    fn present_entry<'d>(
        &self,
        mut m: &'d MeshDef,
        mut k: String,
        warnings: &mut Vec<String>,
    ) -> Result<(&'d MeshDef, String), SceneError> {
        loop {
            let Some(fallback) = &m.fallback else {
                return Ok((m, k));
            };
            let Some(rel) = &m.path else {
                return Err(SceneError::invalid(
                    key(format!("{k}.fallback")),
                    "`fallback` belongs to a mesh loaded from `path`: it stands in when the file does not exist",
                ));
            };
            let full = self.base_dir.join(rel);
            if self.files.exists(&full) {
                return Ok((m, k));
            }
            warnings.push(format!(
                "{}: `{k}`: {} does not exist: using `{k}.fallback` instead",
                self.scene_path.display(),
                full.display()
            ));
            m = fallback;
            k.push_str(".fallback");
        }
    }

    #[allow(
        clippy::too_many_arguments,
        reason = "one call site; splitting the state would obscure it"
    )]
    fn mesh_from_file(
        &self,
        rel: &str,
        k: &str,
        m: &MeshDef,
        materials: &mut Vec<Material>,
        cache: &mut HashMap<PathBuf, CachedObj>,
        warnings: &mut Vec<String>,
    ) -> Result<Mesh, SceneError> {
        for (present, name) in [
            (m.normals.is_some(), "normals"),
            (m.subdivisions.is_some(), "subdivisions"),
            (m.frequency.is_some(), "frequency"),
            (m.min_triangles.is_some(), "min_triangles"),
            (m.count.is_some(), "count"),
            (m.seed.is_some(), "seed"),
            (m.nx.is_some(), "nx"),
            (m.ny.is_some(), "ny"),
            (m.depth.is_some(), "depth"),
        ] {
            if present {
                return Err(SceneError::invalid(
                    key(format!("{k}.{name}")),
                    format!("`{name}` does not apply to a mesh loaded from `path`"),
                ));
            }
        }
        let full = self.base_dir.join(rel);
        let ext = full
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if ext != "obj" {
            return Err(SceneError::invalid(
                key(format!("{k}.path")),
                format!("`{rel}`: mesh files must be Wavefront .obj"),
            ));
        }
        // Read once; named again, the same mesh, shared, whatever each entry's material.
        let cached = match cache.entry(full) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let text = self.files.read_text(e.key(), self.limits.max_file_bytes)?;
                let loaded = obj::parse_obj_str(&text, e.key(), self.files, self.limits)?;
                warnings.extend(loaded.warnings);
                e.insert(CachedObj {
                    mesh: loaded.mesh,
                    own_materials: Some(loaded.materials),
                })
            }
        };
        // The file's own materials join the scene's the first time an entry uses them.
        if m.material.is_none() {
            if let Some(own) = cached.own_materials.take() {
                let count = materials.len() as u64 + own.len() as u64;
                if count > self.limits.max_materials {
                    return Err(SceneError::TooLarge {
                        origin: key(format!("{k}.path")),
                        what: "material",
                        count,
                        limit: self.limits.max_materials,
                    });
                }
                let offset = materials.len() as MaterialId;
                materials.extend(own);
                offset_materials(&mut cached.mesh, offset);
            }
        }
        Ok(cached.mesh.clone())
    }

    fn generated_mesh(
        &self,
        m: &MeshDef,
        k: &str,
        triangles_so_far: u64,
    ) -> Result<Mesh, SceneError> {
        let kind = m.generate.unwrap_or(GenKind::Icosphere);
        let (allowed, count): (&[&str], u64) = match kind {
            GenKind::Icosphere => (
                &["subdivisions"],
                gen::icosphere_triangle_count(require(
                    m.subdivisions,
                    k,
                    "subdivisions",
                    "icosphere",
                )?),
            ),
            GenKind::GeodesicSphere => match (m.frequency, m.min_triangles) {
                (Some(f), None) => (
                    &["frequency", "min_triangles"],
                    gen::geodesic_triangle_count(f),
                ),
                (None, Some(n)) => (&["frequency", "min_triangles"], n),
                _ => {
                    return Err(SceneError::invalid(
                        key(format!("{k}.generate")),
                        "geodesic_sphere needs exactly one of `frequency` or `min_triangles`",
                    ))
                }
            },
            GenKind::RandomSoup => (
                &["count", "seed"],
                u64::from(require(m.count, k, "count", "random_soup")?),
            ),
            GenKind::IntegerGrid => (
                &["nx", "ny"],
                2 * u64::from(require(m.nx, k, "nx", "integer_grid")?)
                    * u64::from(require(m.ny, k, "ny", "integer_grid")?),
            ),
            GenKind::SphereFlake => {
                let depth = require(m.depth, k, "depth", "sphere_flake")?;
                let s = m.subdivisions.unwrap_or(1);
                (
                    &["depth", "subdivisions"],
                    gen::sphere_flake_count(depth).saturating_mul(gen::icosphere_triangle_count(s)),
                )
            }
        };
        for (present, name) in [
            (m.subdivisions.is_some(), "subdivisions"),
            (m.frequency.is_some(), "frequency"),
            (m.min_triangles.is_some(), "min_triangles"),
            (m.count.is_some(), "count"),
            (m.seed.is_some(), "seed"),
            (m.nx.is_some(), "nx"),
            (m.ny.is_some(), "ny"),
            (m.depth.is_some(), "depth"),
            (m.normals.is_some(), "normals"),
        ] {
            if present && !allowed.contains(&name) {
                return Err(SceneError::invalid(
                    key(format!("{k}.{name}")),
                    format!(
                        "`{name}` is not a parameter of generator `{}`",
                        gen_name(kind)
                    ),
                ));
            }
        }
        let total = triangles_so_far.saturating_add(count);
        if total > self.limits.max_triangles {
            return Err(SceneError::TooLarge {
                origin: key(format!("{k}.generate")),
                what: "triangle",
                count: total,
                limit: self.limits.max_triangles,
            });
        }
        let result = match kind {
            GenKind::Icosphere => gen::icosphere(m.subdivisions.unwrap_or(0)),
            GenKind::GeodesicSphere => match m.frequency {
                Some(f) => gen::geodesic_sphere(f),
                None => gen::icosphere_with_at_least(m.min_triangles.unwrap_or(0)),
            },
            GenKind::RandomSoup => gen::random_soup(m.count.unwrap_or(0), m.seed.unwrap_or(0)),
            GenKind::IntegerGrid => gen::integer_grid(m.nx.unwrap_or(0), m.ny.unwrap_or(0)),
            GenKind::SphereFlake => {
                gen::sphere_flake_mesh(m.depth.unwrap_or(0), m.subdivisions.unwrap_or(1))
            }
        };
        result.map_err(|mut e| {
            if let Some(o) = e.origin_mut() {
                o.key = Some(format!("{k}.generate"));
            }
            e
        })
    }
}

/// An OBJ file a scene names: its mesh, and its own materials until an entry without a
/// `material` of its own appends them to the scene's (then the mesh's ids are offset).
struct CachedObj {
    mesh: Mesh,
    own_materials: Option<Vec<Material>>,
}

/// What makes two generated meshes equal: the generator and every parameter.
fn generator_params(m: &MeshDef) -> String {
    format!(
        "{:?}",
        (
            m.generate,
            m.subdivisions,
            m.frequency,
            m.min_triangles,
            m.count,
            m.seed,
            (m.nx, m.ny, m.depth)
        )
    )
}

fn gen_name(kind: GenKind) -> &'static str {
    match kind {
        GenKind::Icosphere => "icosphere",
        GenKind::GeodesicSphere => "geodesic_sphere",
        GenKind::RandomSoup => "random_soup",
        GenKind::IntegerGrid => "integer_grid",
        GenKind::SphereFlake => "sphere_flake",
    }
}

fn require<T>(v: Option<T>, k: &str, name: &str, generator: &str) -> Result<T, SceneError> {
    v.ok_or_else(|| {
        SceneError::invalid(
            key(format!("{k}.generate")),
            format!("generator `{generator}` needs `{name}`"),
        )
    })
}

fn offset_materials(mesh: &mut Mesh, offset: MaterialId) {
    match &mut mesh.materials {
        MeshMaterials::Single(id) => *id += offset,
        MeshMaterials::PerTriangle(ids) => {
            Arc::make_mut(ids).iter_mut().for_each(|id| *id += offset)
        }
    }
}

fn inline_mesh(m: &MeshDef, k: &str) -> Result<Mesh, SceneError> {
    let (Some(positions), Some(indices)) = (&m.positions, &m.indices) else {
        let missing = if m.positions.is_none() {
            "positions"
        } else {
            "indices"
        };
        return Err(SceneError::invalid(
            key(format!("{k}.{missing}")),
            format!("an inline mesh needs both `positions` and `indices` (`{missing}` is missing)"),
        ));
    };
    for name in [
        "subdivisions",
        "frequency",
        "min_triangles",
        "count",
        "seed",
        "nx",
        "ny",
        "depth",
    ] {
        let present = match name {
            "subdivisions" => m.subdivisions.is_some(),
            "frequency" => m.frequency.is_some(),
            "min_triangles" => m.min_triangles.is_some(),
            "count" => m.count.is_some(),
            "seed" => m.seed.is_some(),
            "nx" => m.nx.is_some(),
            "ny" => m.ny.is_some(),
            _ => m.depth.is_some(),
        };
        if present {
            return Err(SceneError::invalid(
                key(format!("{k}.{name}")),
                format!("`{name}` is a generator parameter; this mesh has no `generate`"),
            ));
        }
    }
    let mut mesh = Mesh::new(
        k,
        positions.iter().map(|p| v3(*p)).collect(),
        indices.clone(),
        0,
    );
    if let Some(n) = &m.normals {
        mesh.normals = Arc::new(n.iter().map(|p| v3(*p)).collect());
    }
    Ok(mesh)
}

fn material_from_def(name: &str, m: &MaterialDef) -> Material {
    Material {
        name: name.to_owned(),
        diffuse: m.diffuse.map_or(Vec3::ZERO, v3),
        specular: m.specular.map_or(Vec3::ZERO, |s| v3(s.0)),
        shininess: m.shininess.unwrap_or(0.0),
        mirror: m.mirror.map_or(Vec3::ZERO, |s| v3(s.0)),
        roughness: m.roughness.unwrap_or(0.0),
        transmission: m.transmission.unwrap_or(0.0),
        ior: m.ior.unwrap_or(1.5),
        fresnel: m.fresnel.unwrap_or(true),
        emission: m.emission.map_or(Vec3::ZERO, v3),
    }
}

fn settings_from_def(s: SettingsDef) -> RenderSettings {
    let d = RenderSettings::default();
    let ao = match s.ao {
        Some(a) => AmbientOcclusion {
            enabled: a.enabled.unwrap_or(true),
            radius: a.radius.unwrap_or(d.ao.radius),
            samples: a.samples.unwrap_or(d.ao.samples),
        },
        None => d.ao,
    };
    RenderSettings {
        width: s.width.unwrap_or(d.width),
        height: s.height.unwrap_or(d.height),
        spp: s.spp.unwrap_or(d.spp),
        max_depth: s.max_depth.unwrap_or(d.max_depth),
        background: s.background.map_or(d.background, v3),
        antialias: s.antialias.unwrap_or(d.antialias),
        ao,
    }
}

fn light_from_def(l: &LightDef, i: usize) -> Result<Light, SceneError> {
    let k = format!("lights[{i}]");
    let kind = match l.kind {
        LightKind::Point => "point",
        LightKind::Sphere => "sphere",
        LightKind::Quad => "quad",
        LightKind::Directional => "directional",
    };
    let fields: [(&str, bool); 7] = [
        ("position", l.position.is_some()),
        ("center", l.center.is_some()),
        ("radius", l.radius.is_some()),
        ("corner", l.corner.is_some()),
        ("edge_u", l.edge_u.is_some()),
        ("edge_v", l.edge_v.is_some()),
        ("direction", l.direction.is_some()),
    ];
    let needed: &[&str] = match l.kind {
        LightKind::Point => &["position"],
        LightKind::Sphere => &["center", "radius"],
        LightKind::Quad => &["corner", "edge_u", "edge_v"],
        LightKind::Directional => &["direction"],
    };
    // A key of another kind of light first: it names the line at fault.
    for (name, present) in fields {
        if present && !needed.contains(&name) {
            return Err(SceneError::invalid(
                key(format!("{k}.{name}")),
                format!(
                    "`{name}` is not a key of a {kind} light (it takes {})",
                    needed.join(", ")
                ),
            ));
        }
    }
    for (name, present) in fields {
        if !present && needed.contains(&name) {
            return Err(SceneError::invalid(
                key(k),
                format!("a {kind} light needs `{name}`"),
            ));
        }
    }
    let color = l.color.map_or(Vec3::ONE, v3);
    let intensity = l.intensity.unwrap_or(1.0);
    let get = |v: Option<[f32; 3]>| v.map_or(Vec3::ZERO, v3);
    Ok(match l.kind {
        LightKind::Point => Light::Point {
            position: get(l.position),
            color,
            intensity,
        },
        LightKind::Sphere => Light::Sphere {
            center: get(l.center),
            radius: l.radius.unwrap_or(0.0),
            color,
            intensity,
        },
        LightKind::Quad => Light::Quad {
            corner: get(l.corner),
            edge_u: get(l.edge_u),
            edge_v: get(l.edge_v),
            color,
            intensity,
        },
        LightKind::Directional => Light::Directional {
            direction: get(l.direction),
            color,
            intensity,
        },
    })
}
