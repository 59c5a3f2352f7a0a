//! Wavefront OBJ + MTL, parsed by `tobj` behind a line-numbered validator.
//!
//! `tobj` builds the meshes (triangulation, per-model de-indexing, material
//! groups), but its errors carry no line numbers and a few inputs make it
//! panic (`Kd 1 2` unwraps a short array) or silently misread (`l 1 2 3`
//! becomes a triangle). So every OBJ and MTL line is first checked here,
//! strictly, with `file:line` in every message, and rewritten into a
//! canonical form that `tobj` cannot misread: statements we do not render
//! (`l`, `p`, `vp`, `s`, free-form geometry) become blank lines and are
//! counted in a warning, indices become absolute, `mtllib a b` becomes one
//! `mtllib` per file, colours get three components. `tobj` then parses the
//! canonical text; an error from it after validation would be a bug here,
//! and is reported as such rather than panicking.
//!
//! Checks: numbers parse and are finite, coordinates within
//! [`MAX_COORDINATE`], `w ≠ 0`; face references are non-zero, in range of
//! what was defined *before* the face (negative = relative, as the spec
//! says), at most `v/vt/vn`; at least 3 per face; triangle count within the
//! limit; `usemtl` names a material from an earlier `mtllib`; referenced
//! MTL files exist (error names the path). MTL: statements inside a
//! `newmtl`, colours non-negative, `illum` 0..=10, ranges of `Ns`, `Ni`, `d`,
//! `Tr`, `Pr`.
//!
//! MTL → [`Material`] mapping (see `docs/scene-format.md`): `Kd` diffuse
//! (default 0.8 grey), `Ks` specular, `Ns` shininess, `Ke` emission,
//! `d` (or `1 − Tr`) opacity → `transmission = 1 − d`, `Ni` ior, `illum`
//! 3–9 turns on mirror reflection with reflectance `Ks`, `Pr` (PBR
//! extension) roughness.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::error::{Origin, SceneError};
use super::files::FileSource;
use super::limits::{Limits, MAX_COORDINATE, MAX_IOR, MAX_SHININESS};
use super::material::Material;
use super::model::{MaterialId, Mesh, MeshMaterials};
use super::validate;
use super::{LoadedScene, Scene};

/// A mesh read from an OBJ file, with the materials its triangles index
/// (MTL materials in file order, then a default grey one if some triangles
/// had no `usemtl`).
#[derive(Clone, Debug)]
pub struct ObjMesh {
    /// The merged mesh (all objects and groups), identity transform.
    pub mesh: Mesh,
    /// Materials indexed by the mesh's material ids.
    pub materials: Vec<Material>,
    /// Warnings (ignored statements, dropped normals).
    pub warnings: Vec<String>,
}

fn err_line(path: &Path, line: usize, message: impl Into<String>) -> SceneError {
    SceneError::syntax(Origin::line(path, line), message)
}

fn parse_f32(tok: &str, path: &Path, line: usize, what: &str) -> Result<f32, SceneError> {
    let v: f32 = tok
        .parse()
        .map_err(|_| err_line(path, line, format!("{what}: `{tok}` is not a number")))?;
    if !v.is_finite() {
        return Err(SceneError::NonFinite {
            origin: Origin {
                key: Some(what.to_owned()),
                ..Origin::line(path, line)
            },
            value: tok.to_owned(),
        });
    }
    Ok(v)
}

/// Numbers of the whole argument list.
fn parse_all(args: &[&str], path: &Path, line: usize, what: &str) -> Result<Vec<f32>, SceneError> {
    args.iter()
        .map(|t| parse_f32(t, path, line, what))
        .collect()
}

/// Words of a line after its keyword, and the raw rest (for names).
fn split_line(line: &str) -> Option<(&str, Vec<&str>, &str)> {
    let line = line.trim();
    let mut words = line.split_whitespace();
    let kw = words.next()?;
    let rest = line[kw.len()..].trim();
    Some((kw, words.collect(), rest))
}

/// What was learned from one MTL file.
struct MtlFile {
    canonical: String,
    /// Material names in file order.
    names: Vec<String>,
    warnings: Vec<String>,
}

#[derive(Default)]
struct MtlCheck {
    name: String,
    ks: Option<(Vec3, usize)>,
    illum: Option<u8>,
    ni: Option<(f32, usize)>,
    opacity: Option<(f32, usize)>,
}

impl MtlCheck {
    /// Cross-field checks once a material is complete.
    fn finish(&self, path: &Path) -> Result<(), SceneError> {
        if self.name.is_empty() {
            return Ok(());
        }
        let reflective = matches!(self.illum, Some(3..=9));
        if let (true, Some((ks, line))) = (reflective, self.ks) {
            if ks.max_element() > 1.0 {
                return Err(SceneError::out_of_range(
                    Origin {
                        key: Some(format!("{} Ks", self.name)),
                        ..Origin::line(path, line)
                    },
                    ks,
                    "with illum 3–9, Ks is the mirror reflectance and must be in [0, 1]",
                ));
            }
        }
        let transmissive = self.opacity.is_some_and(|(d, _)| d < 1.0);
        if let (true, Some((ni, line))) = (transmissive, self.ni) {
            if !(ni > 0.0 && ni <= MAX_IOR) {
                return Err(SceneError::out_of_range(
                    Origin {
                        key: Some(format!("{} Ni", self.name)),
                        ..Origin::line(path, line)
                    },
                    ni,
                    format!(
                        "a transparent material needs an index of refraction in (0, {MAX_IOR}]"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Validate MTL text and rewrite it canonically. Errors name `path` and the
/// line.
fn check_mtl(text: &str, path: &Path) -> Result<MtlFile, SceneError> {
    let mut canonical = String::with_capacity(text.len());
    let mut names = Vec::new();
    let mut ignored: HashMap<String, (usize, usize)> = HashMap::new();
    let mut cur = MtlCheck::default();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let Some((kw, args, rest)) = split_line(raw) else {
            canonical.push('\n');
            continue;
        };
        if kw.starts_with('#') {
            canonical.push('\n');
            continue;
        }
        if kw != "newmtl" && cur.name.is_empty() {
            return Err(err_line(
                path,
                ln,
                format!("`{kw}` before the first `newmtl`"),
            ));
        }
        let key = |k: &str| Origin {
            key: Some(format!("{} {k}", cur.name)),
            ..Origin::line(path, ln)
        };
        match kw {
            "newmtl" => {
                cur.finish(path)?;
                if rest.is_empty() {
                    return Err(err_line(path, ln, "`newmtl` needs a name"));
                }
                cur = MtlCheck {
                    name: rest.to_owned(),
                    ..MtlCheck::default()
                };
                names.push(rest.to_owned());
                canonical.push_str("newmtl ");
                canonical.push_str(rest);
            }
            "Ka" | "Kd" | "Ks" | "Ke" | "Tf" => {
                if args
                    .first()
                    .is_some_and(|a| *a == "spectral" || *a == "xyz")
                {
                    return Err(err_line(
                        path,
                        ln,
                        format!("`{kw} {}` colours are not supported: give r g b", args[0]),
                    ));
                }
                let v = parse_all(&args, path, ln, kw)?;
                let c = match v.as_slice() {
                    [g] => Vec3::splat(*g),
                    [r, g, b] => Vec3::new(*r, *g, *b),
                    _ => {
                        return Err(err_line(
                            path,
                            ln,
                            format!("`{kw}` needs 1 or 3 numbers (r g b), found {}", v.len()),
                        ))
                    }
                };
                if c.min_element() < 0.0 {
                    return Err(SceneError::out_of_range(
                        key(kw),
                        c,
                        "colour components must be ≥ 0",
                    ));
                }
                if kw == "Ks" {
                    cur.ks = Some((c, ln));
                }
                canonical.push_str(&format!("{kw} {:?} {:?} {:?}", c.x, c.y, c.z));
            }
            "Ns" | "Ni" | "d" | "Tr" | "Pr" => {
                let args: Vec<&str> = args.into_iter().filter(|a| *a != "-halo").collect();
                let [tok] = args.as_slice() else {
                    return Err(err_line(
                        path,
                        ln,
                        format!("`{kw}` needs exactly one number, found {}", args.len()),
                    ));
                };
                let v = parse_f32(tok, path, ln, kw)?;
                let (ok, range) = match kw {
                    "Ns" => (
                        (0.0..=MAX_SHININESS).contains(&v),
                        format!("must be in [0, {MAX_SHININESS:e}]"),
                    ),
                    "Ni" => (v >= 0.0, "must be ≥ 0".to_owned()),
                    _ => ((0.0..=1.0).contains(&v), "must be in [0, 1]".to_owned()),
                };
                if !ok {
                    return Err(SceneError::out_of_range(key(kw), v, range));
                }
                match kw {
                    "Ni" => cur.ni = Some((v, ln)),
                    "d" => cur.opacity = Some((v, ln)),
                    "Tr" if cur.opacity.is_none() => cur.opacity = Some((1.0 - v, ln)),
                    _ => {}
                }
                canonical.push_str(&format!("{kw} {v:?}"));
            }
            "illum" => {
                let n = match args.as_slice() {
                    [tok] => tok.parse::<u8>().ok().filter(|n| *n <= 10),
                    _ => None,
                };
                let Some(n) = n else {
                    return Err(err_line(path, ln, "`illum` needs one integer in 0..=10"));
                };
                cur.illum = Some(n);
                canonical.push_str(&format!("illum {n}"));
            }
            _ => {
                // Textures and other extensions: not rendered; say so once per
                // keyword.
                let e = ignored.entry(kw.to_owned()).or_insert((ln, 0));
                e.1 += 1;
            }
        }
        canonical.push('\n');
    }
    cur.finish(path)?;
    let mut warnings: Vec<String> = ignored
        .into_iter()
        .map(|(kw, (first, n))| {
            format!(
                "{}:{first}: ignored {n} `{kw}` statement{} (not supported)",
                path.display(),
                if n == 1 { "" } else { "s" }
            )
        })
        .collect();
    warnings.sort();
    Ok(MtlFile {
        canonical,
        names,
        warnings,
    })
}

/// Parse OBJ text. `path` names it in messages, and `mtllib` files are read
/// through `files` relative to its directory.
pub fn parse_obj_str(
    text: &str,
    path: &Path,
    files: &dyn FileSource,
    limits: &Limits,
) -> Result<ObjMesh, SceneError> {
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let mut canonical = String::with_capacity(text.len() + text.len() / 8);
    let mut warnings = Vec::new();
    let (mut nv, mut nvt, mut nvn) = (0u64, 0u64, 0u64);
    let mut triangles: u64 = 0;
    let (mut refs_with_normal, mut refs_without_normal) = (0u64, 0u64);
    let mut known_materials: HashMap<String, ()> = HashMap::new();
    let mut mtl_texts: HashMap<PathBuf, String> = HashMap::new();
    let mut ignored: HashMap<&'static str, (usize, usize)> = HashMap::new();
    let mut ignore = |what: &'static str, ln: usize| {
        let e = ignored.entry(what).or_insert((ln, 0));
        e.1 += 1;
    };

    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let Some((kw, args, rest)) = split_line(raw) else {
            canonical.push('\n');
            continue;
        };
        if kw.starts_with('#') {
            canonical.push('\n');
            continue;
        }
        match kw {
            "v" => {
                let v = parse_all(&args, path, ln, "v")?;
                let p = match v.as_slice() {
                    [x, y, z] | [x, y, z, _, _, _] => Vec3::new(*x, *y, *z),
                    [x, y, z, w] => {
                        if *w == 0.0 {
                            return Err(err_line(path, ln, "vertex weight w is 0"));
                        }
                        Vec3::new(*x, *y, *z) / *w
                    }
                    _ => {
                        return Err(err_line(
                            path,
                            ln,
                            format!(
                                "`v` needs x y z (optionally w, or r g b), found {} numbers",
                                v.len()
                            ),
                        ))
                    }
                };
                if !p.is_finite() || p.abs().max_element() > MAX_COORDINATE {
                    return Err(SceneError::out_of_range(
                        Origin::line(path, ln),
                        p,
                        format!("vertex coordinates must be within ±{MAX_COORDINATE:e}"),
                    ));
                }
                nv += 1;
                if nv > limits.max_vertices {
                    return Err(SceneError::TooLarge {
                        origin: Origin::line(path, ln),
                        what: "vertex",
                        count: nv,
                        limit: limits.max_vertices,
                    });
                }
                canonical.push_str(&format!("v {:?} {:?} {:?}", p.x, p.y, p.z));
            }
            "vt" => {
                let v = parse_all(&args, path, ln, "vt")?;
                let (u, w) = match v.as_slice() {
                    [u] => (*u, 0.0),
                    [u, w] | [u, w, _] => (*u, *w),
                    _ => {
                        return Err(err_line(
                            path,
                            ln,
                            format!("`vt` needs 1 to 3 numbers, found {}", v.len()),
                        ))
                    }
                };
                nvt += 1;
                canonical.push_str(&format!("vt {u:?} {w:?}"));
            }
            "vn" => {
                let v = parse_all(&args, path, ln, "vn")?;
                let [x, y, z] = v.as_slice() else {
                    return Err(err_line(
                        path,
                        ln,
                        format!("`vn` needs 3 numbers, found {}", v.len()),
                    ));
                };
                nvn += 1;
                canonical.push_str(&format!("vn {x:?} {y:?} {z:?}"));
            }
            "f" | "fo" => {
                if args.len() < 3 {
                    return Err(err_line(
                        path,
                        ln,
                        format!("a face needs at least 3 vertices, found {}", args.len()),
                    ));
                }
                canonical.push('f');
                for tok in &args {
                    let parts: Vec<&str> = tok.split('/').collect();
                    if parts.len() > 3 || parts[0].is_empty() {
                        return Err(err_line(
                            path,
                            ln,
                            format!("`{tok}` is not a face vertex (v, v/vt, v//vn or v/vt/vn)"),
                        ));
                    }
                    canonical.push(' ');
                    let lists = [("vertex", nv), ("texture coordinate", nvt), ("normal", nvn)];
                    for (k, part) in parts.iter().enumerate() {
                        if k > 0 {
                            canonical.push('/');
                        }
                        if part.is_empty() {
                            continue;
                        }
                        let (what, count) = lists[k];
                        let index: i64 = part.parse().map_err(|_| {
                            err_line(
                                path,
                                ln,
                                format!("`{tok}`: `{part}` is not an integer index"),
                            )
                        })?;
                        let resolved = if index > 0 {
                            index
                        } else {
                            (count as i64).saturating_add(index).saturating_add(1)
                        };
                        if index == 0 || resolved < 1 || resolved as u64 > count {
                            return Err(SceneError::IndexOutOfRange {
                                origin: Origin::line(path, ln),
                                index,
                                what: format!("the {what} list (so far)"),
                                len: count,
                            });
                        }
                        canonical.push_str(&resolved.to_string());
                    }
                    if parts.len() == 3 && !parts[2].is_empty() {
                        refs_with_normal += 1;
                    } else {
                        refs_without_normal += 1;
                    }
                }
                triangles += args.len() as u64 - 2;
                if triangles > limits.max_triangles {
                    return Err(SceneError::TooLarge {
                        origin: Origin::line(path, ln),
                        what: "triangle",
                        count: triangles,
                        limit: limits.max_triangles,
                    });
                }
            }
            "o" | "g" => {
                canonical.push_str(kw);
                canonical.push(' ');
                canonical.push_str(rest);
            }
            "usemtl" => {
                if rest.is_empty() {
                    return Err(err_line(path, ln, "`usemtl` needs a material name"));
                }
                if !known_materials.contains_key(rest) {
                    let hint = if mtl_texts.is_empty() {
                        " (no `mtllib` before this line)"
                    } else {
                        ""
                    };
                    return Err(SceneError::UnknownName {
                        origin: Origin::line(path, ln),
                        kind: "material",
                        name: rest.to_owned(),
                        hint: format!("{hint}: not defined in any earlier mtllib").into(),
                    });
                }
                canonical.push_str("usemtl ");
                canonical.push_str(rest);
            }
            "mtllib" => {
                if rest.is_empty() {
                    return Err(err_line(path, ln, "`mtllib` needs a file name"));
                }
                // One file whose name may contain spaces, or several names.
                let whole = dir.join(rest);
                let names: Vec<&str> =
                    if args.len() > 1 && files.read_text(&whole, limits.max_file_bytes).is_err() {
                        args.clone()
                    } else {
                        vec![rest]
                    };
                for name in names {
                    let full = dir.join(name);
                    if !mtl_texts.contains_key(&full) {
                        let mtl = files.read_text(&full, limits.max_file_bytes)?;
                        let checked = check_mtl(&mtl, &full)?;
                        warnings.extend(checked.warnings);
                        for n in checked.names {
                            known_materials.insert(n, ());
                        }
                        mtl_texts.insert(full.clone(), checked.canonical);
                    }
                    canonical.push_str("mtllib ");
                    canonical.push_str(&full.to_string_lossy());
                    canonical.push('\n');
                }
                continue;
            }
            "l" => ignore("l (polyline)", ln),
            "p" => ignore("p (point)", ln),
            "s" => ignore("s (smoothing group)", ln),
            "vp" | "cstype" | "deg" | "bmat" | "step" | "curv" | "curv2" | "surf" | "parm"
            | "trim" | "hole" | "scrv" | "sp" | "end" | "con" => ignore("free-form geometry", ln),
            "mg" | "bevel" | "c_interp" | "d_interp" | "lod" | "usemap" | "maplib"
            | "shadow_obj" | "trace_obj" | "ctech" | "stech" => ignore("render attribute", ln),
            _ => {
                return Err(err_line(path, ln, format!("unknown OBJ statement `{kw}`")));
            }
        }
        canonical.push('\n');
    }
    let mut ignored: Vec<_> = ignored.into_iter().collect();
    ignored.sort();
    for (what, (first, n)) in ignored {
        if what != "s (smoothing group)" {
            warnings.push(format!(
                "{}:{first}: ignored {n} `{what}` statement{}",
                path.display(),
                if n == 1 { "" } else { "s" }
            ));
        }
    }

    // tobj on the canonical text.
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let tobj_failed = |e: tobj::LoadError| {
        SceneError::syntax(
            Origin::file(path),
            format!("tobj rejected the file after validation ({e}); this is a vkrt bug, please report it"),
        )
    };
    let (models, mtl_result) = tobj::load_obj_buf(&mut canonical.as_bytes(), &options, |p| {
        match mtl_texts.get(p) {
            Some(t) => tobj::load_mtl_buf(&mut t.as_bytes()),
            None => Err(tobj::LoadError::OpenFileFailed),
        }
    })
    .map_err(tobj_failed)?;
    let tobj_materials = mtl_result.map_err(tobj_failed)?;

    let mut materials: Vec<Material> = tobj_materials.iter().map(material_from_mtl).collect();
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut all_normals = refs_without_normal == 0 && refs_with_normal > 0;
    let mut indices = Vec::new();
    let mut tri_materials: Vec<MaterialId> = Vec::new();
    let mut default_id: Option<MaterialId> = None;
    for model in &models {
        let m = &model.mesh;
        let base = positions.len() as u32;
        positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2])),
        );
        if m.normals.len() == m.positions.len() {
            normals.extend(
                m.normals
                    .chunks_exact(3)
                    .map(|c| Vec3::new(c[0], c[1], c[2])),
            );
        } else {
            all_normals = false;
        }
        let material = match m.material_id {
            Some(id) if id < materials.len() => id as MaterialId,
            _ => *default_id.get_or_insert_with(|| {
                materials.push(Material::default());
                (materials.len() - 1) as MaterialId
            }),
        };
        let before = indices.len();
        indices.extend(
            m.indices
                .chunks_exact(3)
                .map(|c| [c[0] + base, c[1] + base, c[2] + base]),
        );
        tri_materials.extend(std::iter::repeat_n(material, indices.len() - before));
    }
    if !all_normals {
        if refs_with_normal > 0 {
            warnings.push(format!(
                "{}: only some face vertices have normals; using face normals everywhere",
                path.display()
            ));
        }
        normals.clear();
    }
    if materials.is_empty() {
        materials.push(Material::default());
    }
    let single = tri_materials.first().copied().unwrap_or(0);
    let materials_of_mesh = if tri_materials.iter().all(|&m| m == single) {
        MeshMaterials::Single(single)
    } else {
        MeshMaterials::PerTriangle(tri_materials.into())
    };
    let name = path
        .file_name()
        .map_or_else(|| "obj".to_owned(), |n| n.to_string_lossy().into_owned());
    let mut mesh = Mesh::new(&name, positions, indices, 0);
    mesh.normals = normals.into();
    mesh.materials = materials_of_mesh;
    Ok(ObjMesh {
        mesh,
        materials,
        warnings,
    })
}

/// Convert a (validated) `tobj` material.
fn material_from_mtl(m: &tobj::Material) -> Material {
    let v = |c: Option<[f32; 3]>, d: Vec3| c.map_or(d, Vec3::from_array);
    let param = |k: &str| {
        m.unknown_param
            .get(k)
            .and_then(|s| s.trim().parse::<f32>().ok())
    };
    let opacity = m
        .dissolve
        .or_else(|| param("Tr").map(|t| 1.0 - t))
        .unwrap_or(1.0)
        .clamp(0.0, 1.0);
    let transmission = 1.0 - opacity;
    let specular = v(m.specular, Vec3::ZERO);
    let reflective = matches!(m.illumination_model, Some(3..=9));
    let ior = match m.optical_density {
        Some(n) if n > 0.0 && n <= MAX_IOR => n,
        _ if transmission > 0.0 => 1.5,
        _ => 1.0,
    };
    Material {
        name: m.name.clone(),
        diffuse: v(m.diffuse, Vec3::splat(0.8)),
        specular,
        shininess: m.shininess.unwrap_or(0.0),
        mirror: if reflective {
            specular.min(Vec3::ONE)
        } else {
            Vec3::ZERO
        },
        roughness: param("Pr").unwrap_or(0.0).clamp(0.0, 1.0),
        transmission,
        ior,
        fresnel: true,
        emission: v(m.emissive, Vec3::ZERO),
    }
}

/// An `.obj` file as a whole scene: the mesh with a camera framing it and a
/// default light ([`Scene::from_geometry`]), validated.
pub fn load_obj_scene(
    text: &str,
    path: &Path,
    files: &dyn FileSource,
    limits: &Limits,
) -> Result<LoadedScene, SceneError> {
    let obj = parse_obj_str(text, path, files, limits)?;
    let mut warnings = obj.warnings;
    let mut scene = Scene::from_geometry(vec![obj.mesh], Vec::new(), obj.materials);
    let more = validate::validate(&mut scene, limits).map_err(|mut e| {
        if let Some(o) = e.origin_mut() {
            if o.file.is_none() {
                o.file = Some(path.to_owned());
            }
        }
        e
    })?;
    warnings.extend(more.into_iter().map(|w| format!("{}: {w}", path.display())));
    Ok(LoadedScene { scene, warnings })
}
