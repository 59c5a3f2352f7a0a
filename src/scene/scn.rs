//! The plain-text scene format of Bidmon (2010, §4.1.1 and Appendix B).
//!
//! ```text
//! scene file version 1.0
//! Number of lights: 1
//! Number of objects: 3
//! Number of materials: 2
//!
//! <Camera>
//!   position: 0, 0, 1000
//!   direction: 0, 0, -1
//!   up direction: 0, 1, 0
//!   right direction: 1, 0, 0
//!   zoom: 3400
//! <end>
//! <Triangle>
//!   vertices: 30, -100, -150; 100, -100, -100; 30, 0, -150
//!   color: 0.12, 0.57, 0.87
//!   material: 2
//! <next>
//!   ...
//! <end>
//! ```
//!
//! Blocks `<Light>`, `<Sphere>`, `<Triangle>`, `<Material>`, `<Screen>`,
//! `<Camera>` hold `key: values` lines; `<next>` separates objects of the
//! same type, `<end>` closes the block. The header counts must match the
//! file (the thesis allocates memory from them; we check them).
//!
//! The thesis leaves some meanings open; we read them as follows (also in
//! `docs/scene-format.md`):
//! - `zoom` is the distance from the eye to the image plane in pixels, so
//!   the vertical field of view is `2·atan(height / (2·zoom))` (its example,
//!   700 px at zoom 3400, gives 11.8°, which frames its 200-unit scene at
//!   ~1100 units).
//! - Colour is per object and the material is shared, so each (material,
//!   colour) pair becomes one [`Material::scn`].
//! - Lights are points with the given colour; the thesis has no falloff, so
//!   the intensity is the squared distance from the light to the centre of
//!   the scene bounds, which makes the irradiance there equal to `color`.
//! - `depth` is [`RenderSettings::max_depth`]; one sample per pixel, no
//!   anti-aliasing, black background, no ambient term (none in the thesis).

use std::collections::HashMap;
use std::path::Path;

use glam::Vec3;

use super::error::{Origin, SceneError};
use super::limits::Limits;
use super::material::Material;
use super::model::{Camera, Light, MaterialId, Mesh, MeshMaterials, RenderSettings, Sphere};
use super::validate;
use super::{LoadedScene, Scene};

fn at(path: &Path, line: usize) -> Origin {
    Origin::line(path, line)
}

fn syntax(path: &Path, line: usize, msg: impl Into<String>) -> SceneError {
    SceneError::syntax(at(path, line), msg)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Block {
    Light,
    Sphere,
    Triangle,
    Material,
    Screen,
    Camera,
}

impl Block {
    fn parse(tag: &str) -> Option<Self> {
        Some(match tag.to_ascii_lowercase().as_str() {
            "<light>" => Block::Light,
            "<sphere>" => Block::Sphere,
            "<triangle>" => Block::Triangle,
            "<material>" => Block::Material,
            "<screen>" => Block::Screen,
            "<camera>" => Block::Camera,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Block::Light => "<Light>",
            Block::Sphere => "<Sphere>",
            Block::Triangle => "<Triangle>",
            Block::Material => "<Material>",
            Block::Screen => "<Screen>",
            Block::Camera => "<Camera>",
        }
    }

    fn keys(self) -> &'static [&'static str] {
        match self {
            Block::Light => &["position", "color"],
            Block::Sphere => &["position", "radius", "color", "material"],
            Block::Triangle => &["vertices", "color", "material"],
            Block::Material => &[
                "shininess",
                "specular",
                "reflection",
                "refraction",
                "transparency",
            ],
            Block::Screen => &["width", "height", "depth"],
            Block::Camera => &[
                "position",
                "direction",
                "up direction",
                "right direction",
                "zoom",
            ],
        }
    }
}

/// One object: its block, first line, and `key → (value text, line)`.
struct Object {
    block: Block,
    line: usize,
    props: HashMap<String, (String, usize)>,
}

impl Object {
    fn raw(&self, path: &Path, key: &str) -> Result<(&str, usize), SceneError> {
        self.props
            .get(key)
            .map(|(v, l)| (v.as_str(), *l))
            .ok_or_else(|| {
                SceneError::invalid(
                    Origin {
                        key: Some(key.to_owned()),
                        ..at(path, self.line)
                    },
                    format!("{} object is missing `{key}:`", self.block.name()),
                )
            })
    }

    fn number(&self, path: &Path, key: &str) -> Result<f32, SceneError> {
        let (v, line) = self.raw(path, key)?;
        number(v, path, line, key)
    }

    fn opt_number(&self, path: &Path, key: &str, default: f32) -> Result<f32, SceneError> {
        match self.props.get(key) {
            Some((v, line)) => number(v, path, *line, key),
            None => Ok(default),
        }
    }

    fn vec3(&self, path: &Path, key: &str) -> Result<Vec3, SceneError> {
        let (v, line) = self.raw(path, key)?;
        vec3(v, path, line, key)
    }

    fn integer(&self, path: &Path, key: &str) -> Result<(i64, usize), SceneError> {
        let (v, line) = self.raw(path, key)?;
        let n: i64 = v.trim().parse().map_err(|_| {
            syntax(
                path,
                line,
                format!("`{key}`: `{}` is not an integer", v.trim()),
            )
        })?;
        Ok((n, line))
    }
}

fn number(text: &str, path: &Path, line: usize, key: &str) -> Result<f32, SceneError> {
    let t = text.trim();
    let v: f32 = t
        .parse()
        .map_err(|_| syntax(path, line, format!("`{key}`: `{t}` is not a number")))?;
    if !v.is_finite() {
        return Err(SceneError::NonFinite {
            origin: Origin {
                key: Some(key.to_owned()),
                ..at(path, line)
            },
            value: t.to_owned(),
        });
    }
    Ok(v)
}

fn vec3(text: &str, path: &Path, line: usize, key: &str) -> Result<Vec3, SceneError> {
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 3 {
        return Err(syntax(
            path,
            line,
            format!(
                "`{key}` needs 3 comma-separated numbers, found `{}`",
                text.trim()
            ),
        ));
    }
    Ok(Vec3::new(
        number(parts[0], path, line, key)?,
        number(parts[1], path, line, key)?,
        number(parts[2], path, line, key)?,
    ))
}

/// Parse (and validate) a .scn scene. `path` names the text in messages.
pub fn parse_scn(text: &str, path: &Path, limits: &Limits) -> Result<LoadedScene, SceneError> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    let mut header = Vec::with_capacity(4);
    for (ln, l) in lines.by_ref() {
        if l.is_empty() {
            continue;
        }
        header.push((ln, l));
        if header.len() == 4 {
            break;
        }
    }
    let expect = [
        "scene file version",
        "number of lights:",
        "number of objects:",
        "number of materials:",
    ];
    let mut counts = [0u64; 3];
    for (k, prefix) in expect.iter().enumerate() {
        let Some(&(ln, l)) = header.get(k) else {
            return Err(syntax(
                path,
                header.last().map_or(1, |h| h.0),
                format!(".scn header incomplete: expected a line `{prefix} …`"),
            ));
        };
        let lower = l.to_ascii_lowercase();
        let Some(rest) = lower.strip_prefix(prefix) else {
            return Err(syntax(
                path,
                ln,
                format!("expected .scn header line `{prefix} …`, found `{l}`"),
            ));
        };
        let rest = rest.trim();
        if k == 0 {
            number(rest, path, ln, "version")?;
        } else {
            counts[k - 1] = rest
                .parse()
                .map_err(|_| syntax(path, ln, format!("`{rest}` is not a count")))?;
        }
    }

    // Blocks.
    let mut objects: Vec<Object> = Vec::new();
    let mut open: Option<(Block, usize)> = None;
    let mut current: Option<Object> = None;
    for (ln, l) in lines {
        if l.is_empty() {
            continue;
        }
        if l.starts_with('<') {
            let tag = l.to_ascii_lowercase();
            match (tag.as_str(), open) {
                ("<next>", Some((block, _))) => {
                    objects.extend(current.take());
                    current = Some(Object {
                        block,
                        line: ln,
                        props: HashMap::new(),
                    });
                }
                ("<end>", Some(_)) => {
                    objects.extend(current.take());
                    open = None;
                }
                ("<next>" | "<end>", None) => {
                    return Err(syntax(path, ln, format!("`{l}` outside a block")));
                }
                (_, Some((block, start))) => {
                    return Err(syntax(
                        path,
                        ln,
                        format!(
                            "`{l}` inside the {} block opened at line {start} (missing <end>?)",
                            block.name()
                        ),
                    ));
                }
                (_, None) => {
                    let block = Block::parse(l)
                        .ok_or_else(|| syntax(path, ln, format!("unknown block `{l}`")))?;
                    open = Some((block, ln));
                    current = Some(Object {
                        block,
                        line: ln,
                        props: HashMap::new(),
                    });
                }
            }
            if objects.len() as u64 > limits.max_triangles.saturating_add(limits.max_spheres) {
                return Err(SceneError::TooLarge {
                    origin: at(path, ln),
                    what: "object",
                    count: objects.len() as u64,
                    limit: limits.max_triangles.saturating_add(limits.max_spheres),
                });
            }
            continue;
        }
        let Some(obj) = current.as_mut() else {
            return Err(syntax(path, ln, format!("`{l}` outside a block")));
        };
        let Some((key, value)) = l.split_once(':') else {
            return Err(syntax(
                path,
                ln,
                format!("expected `key: value`, found `{l}`"),
            ));
        };
        let key = key.trim().to_ascii_lowercase();
        let key = key.split_whitespace().collect::<Vec<_>>().join(" ");
        if !obj.block.keys().contains(&key.as_str()) {
            return Err(syntax(
                path,
                ln,
                format!(
                    "unknown key `{key}` in {} (expected one of: {})",
                    obj.block.name(),
                    obj.block.keys().join(", ")
                ),
            ));
        }
        if let Some((_, first)) = obj.props.get(&key) {
            return Err(syntax(
                path,
                ln,
                format!("duplicate key `{key}` (first at line {first})"),
            ));
        }
        obj.props.insert(key, (value.to_owned(), ln));
    }
    if let Some((block, start)) = open {
        return Err(syntax(
            path,
            start,
            format!("the {} block opened here has no <end>", block.name()),
        ));
    }
    build(objects, counts, &header, path, limits)
}

fn build(
    objects: Vec<Object>,
    counts: [u64; 3],
    header: &[(usize, &str)],
    path: &Path,
    limits: &Limits,
) -> Result<LoadedScene, SceneError> {
    let mut warnings = Vec::new();
    let count = |b: Block| objects.iter().filter(|o| o.block == b).count() as u64;
    let actual = [
        count(Block::Light),
        count(Block::Sphere) + count(Block::Triangle),
        count(Block::Material),
    ];
    for (k, what) in ["lights", "objects", "materials"].iter().enumerate() {
        if counts[k] != actual[k] {
            return Err(SceneError::invalid(
                at(path, header[k + 1].0),
                format!(
                    "header says {} {what} but the file defines {}",
                    counts[k], actual[k]
                ),
            ));
        }
    }

    // Materials, numbered from 1 in file order.
    let mut seed_materials = Vec::new();
    for o in objects.iter().filter(|o| o.block == Block::Material) {
        seed_materials.push([
            o.opt_number(path, "shininess", 0.0)?,
            o.opt_number(path, "specular", 0.0)?,
            o.opt_number(path, "reflection", 0.0)?,
            o.opt_number(path, "refraction", 1.0)?,
            o.opt_number(path, "transparency", 0.0)?,
        ]);
    }
    let seed_material_lines: Vec<usize> = objects
        .iter()
        .filter(|o| o.block == Block::Material)
        .map(|o| o.line)
        .collect();
    let mut materials: Vec<Material> = Vec::new();
    let mut material_lines: Vec<usize> = Vec::new();
    let mut material_ids: HashMap<(usize, [u32; 3]), MaterialId> = HashMap::new();
    let mut colours_of = vec![0u32; seed_materials.len()];
    let mut material_for = |o: &Object, color: Vec3| -> Result<MaterialId, SceneError> {
        let (n, line) = o.integer(path, "material")?;
        if n < 1 || n as u64 > seed_materials.len() as u64 {
            return Err(SceneError::IndexOutOfRange {
                origin: Origin {
                    key: Some("material".to_owned()),
                    ..at(path, line)
                },
                index: n,
                what: "the material list (numbered from 1)".to_owned(),
                len: seed_materials.len() as u64,
            });
        }
        let k = (n - 1) as usize;
        let bits = color.to_array().map(f32::to_bits);
        Ok(*material_ids.entry((k, bits)).or_insert_with(|| {
            let [sh, sp, refl, ior, tr] = seed_materials[k];
            material_lines.push(seed_material_lines[k]);
            // One model material per (material, colour): "material2",
            // "material2.2", "material2.3", ...
            colours_of[k] += 1;
            let name = if colours_of[k] == 1 {
                format!("material{n}")
            } else {
                format!("material{n}.{}", colours_of[k])
            };
            materials.push(Material::scn(&name, color, sh, sp, refl, ior, tr));
            (materials.len() - 1) as MaterialId
        }))
    };

    let mut spheres = Vec::new();
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let mut tri_materials = Vec::new();
    let mut light_defs = Vec::new();
    let mut settings = RenderSettings {
        spp: 1,
        antialias: false,
        ..RenderSettings::default()
    };
    let mut camera_obj: Option<&Object> = None;
    for o in &objects {
        match o.block {
            Block::Sphere => {
                let color = o.vec3(path, "color")?;
                spheres.push(Sphere::new(
                    o.vec3(path, "position")?,
                    o.number(path, "radius")?,
                    material_for(o, color)?,
                ));
            }
            Block::Triangle => {
                let (v, line) = o.raw(path, "vertices")?;
                let parts: Vec<&str> = v.split(';').collect();
                if parts.len() != 3 {
                    return Err(syntax(
                        path,
                        line,
                        format!(
                            "`vertices` needs 3 points separated by `;`, found {}",
                            parts.len()
                        ),
                    ));
                }
                let base = positions.len() as u32;
                for p in parts {
                    positions.push(vec3(p, path, line, "vertices")?);
                }
                indices.push([base, base + 1, base + 2]);
                let color = o.vec3(path, "color")?;
                tri_materials.push(material_for(o, color)?);
            }
            Block::Light => light_defs.push((o.vec3(path, "position")?, o.vec3(path, "color")?)),
            Block::Screen => {
                for (key, slot) in [
                    ("width", &mut settings.width),
                    ("height", &mut settings.height),
                    ("depth", &mut settings.max_depth),
                ] {
                    if let Some((v, line)) = o.props.get(key) {
                        *slot = v.trim().parse().map_err(|_| {
                            syntax(
                                path,
                                *line,
                                format!("`{key}`: `{}` is not a non-negative integer", v.trim()),
                            )
                        })?;
                    }
                }
            }
            Block::Camera => {
                if let Some(prev) = camera_obj {
                    return Err(syntax(
                        path,
                        o.line,
                        format!("a second <Camera> (the first is at line {})", prev.line),
                    ));
                }
                camera_obj = Some(o);
            }
            Block::Material => {}
        }
    }

    let mut meshes = Vec::new();
    if !indices.is_empty() {
        let mut mesh = Mesh::new("triangles", positions, indices, 0);
        mesh.materials = MeshMaterials::PerTriangle(tri_materials.into());
        meshes.push(mesh);
    }
    let mut scene = Scene {
        meshes,
        spheres,
        materials,
        lights: Vec::new(),
        camera: Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0),
        settings,
        ambient: Vec3::ZERO,
        animation: None,
    };
    match camera_obj {
        Some(o) => scene.camera = camera_from(o, path, &scene.settings, &mut warnings)?,
        None => {
            scene.frame_camera();
            warnings.push(format!(
                "{}: no <Camera>: using one that frames the scene",
                path.display()
            ));
        }
    }
    let center = scene.bounds().center();
    for (position, color) in light_defs {
        let d2 = (center - position).length_squared().max(1e-12);
        scene.lights.push(Light::Point {
            position,
            color,
            intensity: if d2.is_finite() { d2 } else { 1.0 },
        });
    }
    let lines = KeyLines {
        objects: &objects,
        material_lines: &material_lines,
    };
    let more = validate::validate(&mut scene, limits).map_err(|mut e| {
        if let Some(o) = e.origin_mut() {
            if o.file.is_none() {
                o.file = Some(path.to_owned());
                o.line = o
                    .key
                    .as_deref()
                    .and_then(|k| lines.line_of(k))
                    .map(|l| u32::try_from(l).unwrap_or(u32::MAX));
            }
        }
        e
    })?;
    warnings.extend(more.into_iter().map(|w| format!("{}: {w}", path.display())));
    Ok(LoadedScene { scene, warnings })
}

/// Maps validation key paths (`spheres[1].radius`, `settings.width`,
/// `meshes[0].indices[4]`) back to lines of the file.
struct KeyLines<'a> {
    objects: &'a [Object],
    /// Line of the `<Material>` object each derived material came from.
    material_lines: &'a [usize],
}

impl KeyLines<'_> {
    fn nth(&self, block: Block, n: usize) -> Option<&Object> {
        self.objects.iter().filter(|o| o.block == block).nth(n)
    }

    fn prop_line(o: &Object, key: &str) -> usize {
        o.props.get(key).map_or(o.line, |p| p.1)
    }

    fn line_of(&self, key: &str) -> Option<usize> {
        // "name[i].rest" or "name.rest"
        let (head, rest) = key.split_once('.').unwrap_or((key, ""));
        let (name, index) = match head.split_once('[') {
            Some((n, i)) => (n, i.trim_end_matches(']').parse::<usize>().ok()),
            None => (head, None),
        };
        let field = rest.split(['.', '[']).next().unwrap_or("");
        let sub_index = rest
            .split_once('[')
            .and_then(|(_, i)| i.trim_end_matches(']').parse::<usize>().ok());
        match name {
            "settings" => {
                let o = self.nth(Block::Screen, 0)?;
                let k = match field {
                    "max_depth" => "depth",
                    f => f,
                };
                Some(Self::prop_line(o, k))
            }
            "camera" => {
                let o = self.nth(Block::Camera, 0)?;
                let k = match field {
                    "position" => "position",
                    "look_at" | "focus_distance" => "direction",
                    "up" => "up direction",
                    "fov" => "zoom",
                    _ => "",
                };
                Some(Self::prop_line(o, k))
            }
            "lights" => {
                let o = self.nth(Block::Light, index?)?;
                Some(Self::prop_line(o, field))
            }
            "spheres" => {
                let o = self.nth(Block::Sphere, index?)?;
                let k = if field == "center" { "position" } else { field };
                Some(Self::prop_line(o, k))
            }
            "meshes" => {
                let j = sub_index?;
                let tri = if field == "positions" { j / 3 } else { j };
                let o = self.nth(Block::Triangle, tri)?;
                let k = if field == "triangle_materials" {
                    "material"
                } else {
                    "vertices"
                };
                Some(Self::prop_line(o, k))
            }
            "materials" => self.material_lines.get(index?).copied(),
            _ => None,
        }
    }
}

fn camera_from(
    o: &Object,
    path: &Path,
    settings: &RenderSettings,
    warnings: &mut Vec<String>,
) -> Result<Camera, SceneError> {
    let position = o.vec3(path, "position")?;
    let direction = o.vec3(path, "direction")?;
    let up = o.vec3(path, "up direction")?;
    let right = o.vec3(path, "right direction")?;
    let zoom = o.number(path, "zoom")?;
    let line_of = |k: &str| o.props.get(k).map_or(o.line, |p| p.1);
    if zoom <= 0.0 {
        return Err(SceneError::out_of_range(
            Origin {
                key: Some("zoom".to_owned()),
                ..at(path, line_of("zoom"))
            },
            zoom,
            "zoom (image-plane distance in pixels) must be > 0",
        ));
    }
    let (d, u, r) = (
        direction.normalize_or_zero(),
        up.normalize_or_zero(),
        right.normalize_or_zero(),
    );
    for (v, k) in [
        (d, "direction"),
        (u, "up direction"),
        (r, "right direction"),
    ] {
        if v == Vec3::ZERO {
            return Err(SceneError::invalid(
                Origin {
                    key: Some(k.to_owned()),
                    ..at(path, line_of(k))
                },
                format!("`{k}` must not be zero"),
            ));
        }
    }
    const TOLERANCE: f32 = 1e-3;
    if d.dot(u).abs() > TOLERANCE {
        return Err(SceneError::invalid(
            Origin {
                key: Some("up direction".to_owned()),
                ..at(path, line_of("up direction"))
            },
            format!("`up direction` {up} must be perpendicular to `direction` {direction}"),
        ));
    }
    if r.dot(d).abs() > TOLERANCE || r.dot(u).abs() > TOLERANCE {
        return Err(SceneError::invalid(
            Origin {
                key: Some("right direction".to_owned()),
                ..at(path, line_of("right direction"))
            },
            format!(
                "`right direction` {right} must be perpendicular to `direction` and `up direction`"
            ),
        ));
    }
    if r.dot(d.cross(u)) < 0.0 {
        warnings.push(format!(
            "{}:{}: `right direction` is left-handed (−direction × up); the image will not be mirrored",
            path.display(),
            line_of("right direction")
        ));
    }
    let fov = 2.0 * (settings.height as f32 / (2.0 * zoom)).atan().to_degrees();
    Ok(Camera {
        fov,
        focus_distance: direction.length(),
        ..Camera::look_at(position, position + direction, up, fov)
    })
}
