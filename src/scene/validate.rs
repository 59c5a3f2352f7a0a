//! The one validation pass every scene goes through.
//!
//! Loaders and generators build a [`Scene`], then call [`validate`]; the
//! renderer may therefore assume: every number finite; every index in
//! range; colours non-negative; radii, image sizes, fields of view and
//! sample counts inside their documented ranges ([`super::limits`]);
//! counts below the size limits; no zero-area triangles (they are dropped
//! and counted in a warning — they can never be hit and only cost
//! acceleration-structure memory); at least one triangle or sphere.
//!
//! Animated scenes also have a frame rate and count within their limits
//! ([`MAX_FPS`], [`MAX_FRAMES`]) and every frame's time within
//! [`MAX_TIME`]; keyframes have finite fields, strictly increasing times
//! and no scale component that is zero or changes sign between two keys
//! (the interpolated scale would pass through zero).
//!
//! Errors name the offending item by key path in the TOML format's terms
//! (`spheres[2].radius`, `camera.fov`, `meshes[0].indices[17]`), with
//! materials as `materials[i]`; the TOML loader turns paths into line
//! numbers, the other loaders add their file.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use glam::{DVec3, Vec3};

use super::animation::Keyframe;
use super::error::{Origin, SceneError};
use super::limits::*;
use super::material::Material;
use super::model::{Light, MaterialId, MeshMaterials, Motion, Transform};
use super::Scene;

fn key(k: impl Into<String>) -> Origin {
    Origin::key(k)
}

fn finite(v: f32, k: &str) -> Result<(), SceneError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(SceneError::NonFinite {
            origin: key(k),
            value: v.to_string(),
        })
    }
}

fn finite3(v: Vec3, k: &str) -> Result<(), SceneError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(SceneError::NonFinite {
            origin: key(k),
            value: v.to_string(),
        })
    }
}

/// Finite and every component within ±[`MAX_COORDINATE`].
fn coord3(v: Vec3, k: &str) -> Result<(), SceneError> {
    finite3(v, k)?;
    if v.abs().max_element() > MAX_COORDINATE {
        return Err(SceneError::out_of_range(
            key(k),
            v,
            format!("coordinates must be within ±{MAX_COORDINATE:e}"),
        ));
    }
    Ok(())
}

fn color3(v: Vec3, k: &str) -> Result<(), SceneError> {
    finite3(v, k)?;
    if v.min_element() < 0.0 {
        return Err(SceneError::out_of_range(
            key(k),
            v,
            "colour components must be ≥ 0",
        ));
    }
    Ok(())
}

fn unit_range(v: f32, k: &str) -> Result<(), SceneError> {
    finite(v, k)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(SceneError::out_of_range(key(k), v, "must be in [0, 1]"));
    }
    Ok(())
}

fn positive(v: f32, k: &str) -> Result<(), SceneError> {
    finite(v, k)?;
    if v <= 0.0 {
        return Err(SceneError::out_of_range(key(k), v, "must be > 0"));
    }
    Ok(())
}

fn non_negative(v: f32, k: &str) -> Result<(), SceneError> {
    finite(v, k)?;
    if v < 0.0 {
        return Err(SceneError::out_of_range(key(k), v, "must be ≥ 0"));
    }
    Ok(())
}

fn count_limit(what: &'static str, count: u64, limit: u64, k: &str) -> Result<(), SceneError> {
    if count > limit {
        return Err(SceneError::TooLarge {
            origin: key(k),
            what,
            count,
            limit,
        });
    }
    Ok(())
}

fn material_ref(id: u32, n_materials: usize, k: &str) -> Result<(), SceneError> {
    if id as usize >= n_materials {
        return Err(SceneError::IndexOutOfRange {
            origin: key(k),
            index: i64::from(id),
            what: "the material list".to_owned(),
            len: n_materials as u64,
        });
    }
    Ok(())
}

fn motion(m: &Motion, k: &str) -> Result<(), SceneError> {
    finite3(m.velocity, &format!("{k}.velocity"))?;
    if m.velocity.abs().max_element() > MAX_COORDINATE {
        return Err(SceneError::out_of_range(
            key(format!("{k}.velocity")),
            m.velocity,
            format!("must be within ±{MAX_COORDINATE:e}"),
        ));
    }
    if let Some(o) = &m.orbit {
        coord3(o.center, &format!("{k}.orbit.center"))?;
        finite3(o.axis, &format!("{k}.orbit.axis"))?;
        if o.axis.length_squared() == 0.0 || !o.axis.length_squared().is_finite() {
            return Err(SceneError::out_of_range(
                key(format!("{k}.orbit.axis")),
                o.axis,
                "must be a non-zero vector of moderate length",
            ));
        }
        finite(
            o.degrees_per_second,
            &format!("{k}.orbit.degrees_per_second"),
        )?;
    }
    Ok(())
}

/// `translate`, `rotate`, `scale` of a mesh or keyframe at `k`.
fn transform(t: &Transform, k: &str) -> Result<(), SceneError> {
    finite3(t.translate, &format!("{k}.translate"))?;
    finite3(t.rotate, &format!("{k}.rotate"))?;
    finite3(t.scale, &format!("{k}.scale"))?;
    if t.scale.abs().min_element() == 0.0 {
        return Err(SceneError::out_of_range(
            key(format!("{k}.scale")),
            t.scale,
            "no scale component may be zero",
        ));
    }
    Ok(())
}

/// A mesh's keyframes: each a valid transform at a finite time, times
/// strictly increasing, scales keeping their signs from key to key.
fn keyframes(keys: &[Keyframe], mesh: &str) -> Result<(), SceneError> {
    for (j, kf) in keys.iter().enumerate() {
        let k = format!("{mesh}.keyframes[{j}]");
        finite(kf.time, &format!("{k}.time"))?;
        if kf.time.abs() > MAX_TIME {
            return Err(SceneError::out_of_range(
                key(format!("{k}.time")),
                kf.time,
                format!("times must be within ±{MAX_TIME:e} s"),
            ));
        }
        coord3(kf.transform.translate, &format!("{k}.translate"))?;
        transform(&kf.transform, &k)?;
        let Some(prev) = j.checked_sub(1).map(|p| &keys[p]) else {
            continue;
        };
        if kf.time <= prev.time {
            return Err(SceneError::invalid(
                key(format!("{k}.time")),
                format!(
                    "keyframe times must increase strictly: {} s follows {} s",
                    kf.time, prev.time
                ),
            ));
        }
        let (a, b) = (prev.transform.scale, kf.transform.scale);
        // Signs, not the product, which can underflow to zero.
        if (a.signum() * b.signum()).min_element() < 0.0 {
            return Err(SceneError::invalid(
                key(format!("{k}.scale")),
                format!(
                    "scale {b} flips the sign of a component of the previous key's {a}: the mesh would pass through zero scale in between"
                ),
            ));
        }
    }
    Ok(())
}

fn validate_animation(scene: &Scene) -> Result<(), SceneError> {
    let Some(a) = &scene.animation else {
        return Ok(());
    };
    fps(a.fps, "animation.fps")?;
    if a.frames == 0 || a.frames > MAX_FRAMES {
        return Err(SceneError::out_of_range(
            key("animation.frames"),
            a.frames,
            format!("the frame count must be 1 ..= {MAX_FRAMES}"),
        ));
    }
    // Shutter times are checked already; the last frame shifts them.
    let last = a.frame_time(a.frames - 1);
    let close = scene.camera.shutter_close + last;
    if !close.is_finite() || close > MAX_TIME {
        return Err(SceneError::out_of_range(
            key("animation.frames"),
            format!("{} frames at {} fps", a.frames, a.fps),
            format!(
                "the last frame's shutter closes at {close} s: every time must be within ±{MAX_TIME:e} s"
            ),
        ));
    }
    Ok(())
}

/// A frame rate: finite, in (0, [`MAX_FPS`]].
pub(crate) fn fps(v: f32, k: &str) -> Result<(), SceneError> {
    finite(v, k)?;
    if !(v > 0.0 && v <= MAX_FPS) {
        return Err(SceneError::out_of_range(
            key(k),
            v,
            format!("frames per second must be in (0, {MAX_FPS}]"),
        ));
    }
    Ok(())
}

/// Validate `scene` in place (dropping zero-area triangles) against
/// `limits` and the documented constants. Returns warnings.
pub fn validate(scene: &mut Scene, limits: &Limits) -> Result<Vec<String>, SceneError> {
    let mut warnings = Vec::new();
    validate_settings(scene)?;
    color3(scene.ambient, "ambient")?;
    validate_camera(scene)?;
    validate_animation(scene)?;

    count_limit(
        "material",
        scene.materials.len() as u64,
        limits.max_materials,
        "materials",
    )?;
    for (i, m) in scene.materials.iter().enumerate() {
        validate_material(m, &format!("materials[{i}]"))?;
    }
    count_limit(
        "light",
        scene.lights.len() as u64,
        limits.max_lights,
        "lights",
    )?;
    for (i, l) in scene.lights.iter().enumerate() {
        validate_light(l, &format!("lights[{i}]"))?;
    }

    let n_materials = scene.materials.len();
    count_limit(
        "sphere",
        scene.spheres.len() as u64,
        limits.max_spheres,
        "spheres",
    )?;
    for (i, s) in scene.spheres.iter().enumerate() {
        let k = format!("spheres[{i}]");
        coord3(s.center, &format!("{k}.center"))?;
        positive(s.radius, &format!("{k}.radius"))?;
        if s.radius > MAX_COORDINATE {
            return Err(SceneError::out_of_range(
                key(format!("{k}.radius")),
                s.radius,
                format!("must be ≤ {MAX_COORDINATE:e}"),
            ));
        }
        material_ref(s.material, n_materials, &format!("{k}.material"))?;
        motion(&s.motion, &k)?;
    }

    count_limit(
        "mesh",
        scene.meshes.len() as u64,
        limits.max_meshes,
        "meshes",
    )?;
    // A mesh named more than once shares its geometry: held, checked and counted once.
    let mut seen = HashSet::new();
    let (mut unique_tris, mut unique_verts) = (0u64, 0u64);
    for m in &scene.meshes {
        if seen.insert(Arc::as_ptr(&m.indices)) {
            unique_tris += m.indices.len() as u64;
            unique_verts += m.positions.len() as u64;
        }
    }
    count_limit("triangle", unique_tris, limits.max_triangles, "meshes")?;
    count_limit("vertex", unique_verts, limits.max_vertices, "meshes")?;
    let total_tris: u64 = scene.meshes.iter().map(|m| m.indices.len() as u64).sum();
    count_limit(
        "instanced triangle",
        total_tris,
        limits.max_instanced_triangles,
        "meshes",
    )?;

    let mut dropped_total = 0usize;
    let mut checked: HashMap<GeometryKey, Checked> = HashMap::new();
    for (i, mesh) in scene.meshes.iter_mut().enumerate() {
        let k = format!("meshes[{i}]");
        transform(&mesh.transform, &k)?;
        keyframes(&mesh.keyframes, &k)?;
        motion(&mesh.motion, &k)?;
        if let MeshMaterials::Single(id) = mesh.materials {
            material_ref(id, n_materials, &format!("{k}.material"))?;
        }
        let geometry = GeometryKey::of(mesh);
        if let Some(c) = checked.get(&geometry) {
            c.apply_to(mesh);
            dropped_total += c.dropped;
            continue;
        }
        let nv = mesh.positions.len();
        for (j, p) in mesh.positions.iter().enumerate() {
            if !p.is_finite() || p.abs().max_element() > MAX_COORDINATE {
                coord3(*p, &format!("{k}.positions[{j}]"))?;
            }
        }
        if !mesh.normals.is_empty() {
            if mesh.normals.len() != nv {
                return Err(SceneError::invalid(
                    key(format!("{k}.normals")),
                    format!(
                        "has {} normals for {nv} positions (must be equal, or no normals)",
                        mesh.normals.len()
                    ),
                ));
            }
            for (j, n) in mesh.normals.iter().enumerate() {
                finite3(*n, &format!("{k}.normals[{j}]"))?;
            }
            if let Some(j) = mesh
                .normals
                .iter()
                .position(|n| !n.length_squared().is_normal())
            {
                warnings.push(format!(
                    "mesh `{}` ({k}): normal {j} has zero length; using face normals for the whole mesh",
                    mesh.name
                ));
                mesh.normals = Arc::default();
            }
        }
        for (j, tri) in mesh.indices.iter().enumerate() {
            for &v in tri {
                if v as usize >= nv {
                    return Err(SceneError::IndexOutOfRange {
                        origin: key(format!("{k}.indices[{j}]")),
                        index: i64::from(v),
                        what: format!("mesh `{}` vertex list", mesh.name),
                        len: nv as u64,
                    });
                }
            }
        }
        match &mesh.materials {
            MeshMaterials::Single(_) => {}
            MeshMaterials::PerTriangle(ids) => {
                if ids.len() != mesh.indices.len() {
                    return Err(SceneError::invalid(
                        key(format!("{k}.triangle_materials")),
                        format!(
                            "has {} entries for {} triangles (must be equal)",
                            ids.len(),
                            mesh.indices.len()
                        ),
                    ));
                }
                for (j, id) in ids.iter().enumerate() {
                    material_ref(*id, n_materials, &format!("{k}.triangle_materials[{j}]"))?;
                }
            }
        }
        let dropped = drop_zero_area(mesh);
        if dropped > 0 {
            warnings.push(format!(
                "mesh `{}` ({k}): dropped {dropped} zero-area triangle{}",
                mesh.name,
                if dropped == 1 { "" } else { "s" }
            ));
            dropped_total += dropped;
        }
        checked.insert(geometry, Checked::of(mesh, dropped));
    }

    if scene.triangle_count() == 0 && scene.spheres.is_empty() {
        let detail = if dropped_total > 0 {
            format!(" (all {dropped_total} triangles had zero area)")
        } else {
            String::new()
        };
        return Err(SceneError::Empty {
            origin: Origin::default(),
            detail,
        });
    }

    // Transforms, keyframes and motion must keep everything inside the
    // coordinate limit, during the shutter of every frame.
    let c = &scene.camera;
    let last = scene.frame_time(scene.frame_count() - 1);
    let b = scene.swept_bounds_over(c.shutter_open, c.shutter_close + last);
    if !b.is_empty()
        && (!b.min.is_finite()
            || !b.max.is_finite()
            || b.min.abs().max(b.max.abs()).max_element() > MAX_COORDINATE)
    {
        return Err(SceneError::out_of_range(
            Origin::default(),
            format!("world bounds [{} .. {}]", b.min, b.max),
            format!(
                "transformed and moving geometry must stay within ±{MAX_COORDINATE:e} during the shutter interval of every frame"
            ),
        ));
    }

    let lit = scene.lights.iter().any(|l| l.power().max_element() > 0.0)
        || scene.materials.iter().any(Material::emits)
        || scene.ambient.max_element() > 0.0
        || scene.settings.ao.enabled;
    if !lit {
        warnings.push(
            "scene has no lights, no emissive materials, no ambient light and no AO: the image will show only the background".to_owned(),
        );
    }
    Ok(warnings)
}

/// Remove triangles whose area is exactly zero (repeated vertices or
/// collinear points), computed in f64 so tiny but valid triangles are kept.
/// Returns how many were removed.
pub fn drop_zero_area(mesh: &mut super::Mesh) -> usize {
    let p = &mesh.positions;
    let keep: Vec<bool> = mesh
        .indices
        .iter()
        .map(|&[a, b, c]| {
            match (p.get(a as usize), p.get(b as usize), p.get(c as usize)) {
                (Some(a), Some(b), Some(c)) => {
                    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                    (b - a).cross(c - a) != DVec3::ZERO
                }
                // Out-of-range indices are validation's business, not ours.
                _ => true,
            }
        })
        .collect();
    let dropped = keep.iter().filter(|k| !**k).count();
    if dropped == 0 {
        return 0;
    }
    let mut it = keep.iter();
    Arc::make_mut(&mut mesh.indices).retain(|_| *it.next().unwrap_or(&true));
    if let MeshMaterials::PerTriangle(ids) = &mut mesh.materials {
        let mut it = keep.iter();
        Arc::make_mut(ids).retain(|_| *it.next().unwrap_or(&true));
    }
    dropped
}

/// A mesh's shared geometry, by identity: entries naming the same file or generator hold
/// the same `Arc`s (and per-triangle materials, where they have them).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct GeometryKey([usize; 4]);

impl GeometryKey {
    fn of(mesh: &super::Mesh) -> Self {
        let materials = match &mesh.materials {
            MeshMaterials::Single(_) => 0,
            MeshMaterials::PerTriangle(ids) => Arc::as_ptr(ids) as usize,
        };
        Self([
            Arc::as_ptr(&mesh.positions) as usize,
            Arc::as_ptr(&mesh.normals) as usize,
            Arc::as_ptr(&mesh.indices) as usize,
            materials,
        ])
    }
}

/// What checking one geometry left (normals dropped, zero-area triangles dropped): every
/// other entry naming it takes the same, still shared.
struct Checked {
    normals: Arc<Vec<Vec3>>,
    indices: Arc<Vec<[u32; 3]>>,
    materials: Option<Arc<Vec<MaterialId>>>,
    dropped: usize,
}

impl Checked {
    fn of(mesh: &super::Mesh, dropped: usize) -> Self {
        Self {
            normals: mesh.normals.clone(),
            indices: mesh.indices.clone(),
            materials: match &mesh.materials {
                MeshMaterials::Single(_) => None,
                MeshMaterials::PerTriangle(ids) => Some(ids.clone()),
            },
            dropped,
        }
    }

    fn apply_to(&self, mesh: &mut super::Mesh) {
        mesh.normals = self.normals.clone();
        mesh.indices = self.indices.clone();
        if let (MeshMaterials::PerTriangle(ids), Some(m)) = (&mut mesh.materials, &self.materials) {
            *ids = m.clone();
        }
    }
}

fn validate_settings(scene: &Scene) -> Result<(), SceneError> {
    let s = &scene.settings;
    for (v, k) in [(s.width, "settings.width"), (s.height, "settings.height")] {
        if v == 0 || v > MAX_RESOLUTION {
            return Err(SceneError::out_of_range(
                key(k),
                v,
                format!("image size must be 1 ..= {MAX_RESOLUTION} pixels"),
            ));
        }
    }
    let pixels = u64::from(s.width) * u64::from(s.height);
    if pixels > MAX_PIXELS {
        return Err(SceneError::out_of_range(
            key("settings.width"),
            format!("{} × {} = {pixels} pixels", s.width, s.height),
            format!("image area must be ≤ {MAX_PIXELS} pixels"),
        ));
    }
    if s.spp == 0 || s.spp > MAX_SPP {
        return Err(SceneError::out_of_range(
            key("settings.spp"),
            s.spp,
            format!("samples per pixel must be 1 ..= {MAX_SPP}"),
        ));
    }
    if s.max_depth > MAX_DEPTH {
        return Err(SceneError::out_of_range(
            key("settings.max_depth"),
            s.max_depth,
            format!("must be 0 ..= {MAX_DEPTH}"),
        ));
    }
    color3(s.background, "settings.background")?;
    if s.ao.enabled {
        positive(s.ao.radius, "settings.ao.radius")?;
        if s.ao.samples == 0 || s.ao.samples > MAX_AO_SAMPLES {
            return Err(SceneError::out_of_range(
                key("settings.ao.samples"),
                s.ao.samples,
                format!("must be 1 ..= {MAX_AO_SAMPLES}"),
            ));
        }
    } else {
        finite(s.ao.radius, "settings.ao.radius")?;
    }
    Ok(())
}

fn validate_camera(scene: &Scene) -> Result<(), SceneError> {
    let c = &scene.camera;
    coord3(c.position, "camera.position")?;
    coord3(c.look_at, "camera.look_at")?;
    finite3(c.up, "camera.up")?;
    let forward = c.look_at - c.position;
    if forward.length_squared() == 0.0 {
        return Err(SceneError::invalid(
            key("camera.look_at"),
            format!("look_at {} equals the camera position", c.look_at),
        ));
    }
    let f = forward.normalize();
    let up = c.up.normalize_or_zero();
    if up == Vec3::ZERO || f.cross(up).length() < 1e-6 {
        return Err(SceneError::invalid(
            key("camera.up"),
            format!("up {} is zero or parallel to the view direction {f}", c.up),
        ));
    }
    finite(c.fov, "camera.fov")?;
    if !(c.fov > 0.0 && c.fov < 180.0) {
        return Err(SceneError::out_of_range(
            key("camera.fov"),
            c.fov,
            "vertical field of view must be in (0, 180) degrees",
        ));
    }
    non_negative(c.aperture_radius, "camera.aperture")?;
    if c.aperture_radius > MAX_COORDINATE {
        return Err(SceneError::out_of_range(
            key("camera.aperture"),
            c.aperture_radius,
            format!("must be ≤ {MAX_COORDINATE:e}"),
        ));
    }
    positive(c.focus_distance, "camera.focus_distance")?;
    finite(c.shutter_open, "camera.shutter")?;
    finite(c.shutter_close, "camera.shutter")?;
    if c.shutter_open.abs() > MAX_TIME || c.shutter_close.abs() > MAX_TIME {
        return Err(SceneError::out_of_range(
            key("camera.shutter"),
            format!("[{}, {}]", c.shutter_open, c.shutter_close),
            format!("times must be within ±{MAX_TIME:e} s"),
        ));
    }
    if c.shutter_close < c.shutter_open {
        return Err(SceneError::out_of_range(
            key("camera.shutter"),
            format!("[{}, {}]", c.shutter_open, c.shutter_close),
            "the shutter must close no earlier than it opens",
        ));
    }
    Ok(())
}

fn validate_material(m: &Material, k: &str) -> Result<(), SceneError> {
    color3(m.diffuse, &format!("{k}.diffuse"))?;
    color3(m.specular, &format!("{k}.specular"))?;
    non_negative(m.shininess, &format!("{k}.shininess"))?;
    if m.shininess > MAX_SHININESS {
        return Err(SceneError::out_of_range(
            key(format!("{k}.shininess")),
            m.shininess,
            format!("must be ≤ {MAX_SHININESS:e}"),
        ));
    }
    color3(m.mirror, &format!("{k}.mirror"))?;
    if m.mirror.max_element() > 1.0 {
        return Err(SceneError::out_of_range(
            key(format!("{k}.mirror")),
            m.mirror,
            "mirror reflectance must be in [0, 1]",
        ));
    }
    unit_range(m.roughness, &format!("{k}.roughness"))?;
    unit_range(m.transmission, &format!("{k}.transmission"))?;
    positive(m.ior, &format!("{k}.ior"))?;
    if m.ior > MAX_IOR {
        return Err(SceneError::out_of_range(
            key(format!("{k}.ior")),
            m.ior,
            format!("index of refraction must be in (0, {MAX_IOR}]"),
        ));
    }
    color3(m.emission, &format!("{k}.emission"))?;
    Ok(())
}

fn validate_light(l: &Light, k: &str) -> Result<(), SceneError> {
    match *l {
        Light::Point {
            position,
            color,
            intensity,
        } => {
            coord3(position, &format!("{k}.position"))?;
            color3(color, &format!("{k}.color"))?;
            non_negative(intensity, &format!("{k}.intensity"))?;
        }
        Light::Sphere {
            center,
            radius,
            color,
            intensity,
        } => {
            coord3(center, &format!("{k}.center"))?;
            positive(radius, &format!("{k}.radius"))?;
            color3(color, &format!("{k}.color"))?;
            non_negative(intensity, &format!("{k}.intensity"))?;
        }
        Light::Quad {
            corner,
            edge_u,
            edge_v,
            color,
            intensity,
        } => {
            coord3(corner, &format!("{k}.corner"))?;
            coord3(edge_u, &format!("{k}.edge_u"))?;
            coord3(edge_v, &format!("{k}.edge_v"))?;
            if edge_u.as_dvec3().cross(edge_v.as_dvec3()) == DVec3::ZERO {
                return Err(SceneError::invalid(
                    key(format!("{k}.edge_v")),
                    format!("quad light edges {edge_u} and {edge_v} are parallel or zero: the light has no area"),
                ));
            }
            color3(color, &format!("{k}.color"))?;
            non_negative(intensity, &format!("{k}.intensity"))?;
        }
        Light::Directional {
            direction,
            color,
            intensity,
        } => {
            finite3(direction, &format!("{k}.direction"))?;
            if direction.normalize_or_zero() == Vec3::ZERO {
                return Err(SceneError::invalid(
                    key(format!("{k}.direction")),
                    "direction must not be zero",
                ));
            }
            color3(color, &format!("{k}.color"))?;
            non_negative(intensity, &format!("{k}.intensity"))?;
        }
    }
    Ok(())
}
