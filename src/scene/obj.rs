//! Wavefront OBJ + MTL, read statement by statement behind a line-numbered
//! validator.
//!
//! Every OBJ and MTL line is checked here, strictly, with `file:line` in
//! every message; statements we do not render (`l`, `p`, `vp`, `s`,
//! free-form geometry) are counted in a warning. An OBJ's geometry goes
//! straight into the mesh's arrays as its lines are read (a file on disk is
//! read line by line, [`parse_obj_file`], never whole), with `tobj`'s
//! semantics (`tobj::GPU_LOAD_OPTIONS`: triangle fans, one vertex per
//! distinct `v/vt/vn` reference within a model, models merged in order; see
//! `ObjParser`), so a 10 M-triangle mesh needs little more than the mesh.
//! `tobj` parses the MTL files, from a canonical form of each that it cannot
//! misread (its errors carry no line numbers, and a few inputs make it panic:
//! `Kd 1 2` unwraps a short array): colours get three components, unsupported
//! statements become blank lines; an error from it after validation would be
//! a bug here, and is reported as such rather than panicking.
//!
//! Checks: numbers parse and are finite, coordinates within
//! [`MAX_COORDINATE`], `w ≠ 0`; face references are non-zero, in range of
//! what was defined *before* the face (negative = relative, as the spec
//! says), at most `v/vt/vn`; at least 3 per face; triangle count within the
//! limit; `usemtl` names a material from an earlier `mtllib`. A missing
//! MTL file is a warning naming its path, as OBJ loaders have it, and a
//! `usemtl` then naming no material read gets the default one (with a
//! warning); an unreadable one is an error. MTL: statements inside a
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
use super::files::{invalid_utf8, open_regular, FileSource};
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
    let mut obj = ObjParser::new(path, files, limits);
    for (i, raw) in text.lines().enumerate() {
        obj.line(i + 1, raw)?;
    }
    obj.finish()
}

/// Parse the OBJ file at `path`, line by line as it is read (never the whole text at once),
/// refusing what is not a regular file or is larger than `limits.max_file_bytes`; `mtllib`
/// files are read through `files` relative to its directory. The mesh and the messages are
/// those of [`parse_obj_str`] on the file's text.
pub fn parse_obj_file(
    path: &Path,
    files: &dyn FileSource,
    limits: &Limits,
) -> Result<ObjMesh, SceneError> {
    use std::io::BufRead;
    let io_err = |source: std::io::Error| SceneError::Io {
        path: path.to_owned(),
        source,
    };
    let mut reader =
        std::io::BufReader::with_capacity(1 << 16, open_regular(path, limits.max_file_bytes)?.0);
    let mut obj = ObjParser::new(path, files, limits);
    let mut bytes = Vec::new();
    let mut read: u64 = 0;
    for ln in 1.. {
        bytes.clear();
        let n = reader.read_until(b'\n', &mut bytes).map_err(io_err)?;
        if n == 0 {
            break;
        }
        read += n as u64;
        // (a file that grows while it is read)
        if read > limits.max_file_bytes {
            return Err(SceneError::TooLarge {
                origin: Origin::file(path),
                what: "file byte",
                count: read,
                limit: limits.max_file_bytes,
            });
        }
        let line = match std::str::from_utf8(&bytes) {
            Ok(line) => line,
            Err(e) => return Err(invalid_utf8(path, ln, &bytes, e.valid_up_to())),
        };
        let line = line.strip_suffix('\n').unwrap_or(line);
        obj.line(ln, line.strip_suffix('\r').unwrap_or(line))?;
    }
    obj.finish()
}

/// No texture coordinate or normal in a face vertex.
const NONE: u32 = u32::MAX;

/// An OBJ file read statement by statement: every line checked (with `file:line` in every
/// message) and its geometry added straight to the mesh's arrays, so that nothing but
/// the positions and normals the file defined and the mesh itself is held.
///
/// The mesh is what `tobj` makes of the statements with triangulation and a single index
/// (`tobj::GPU_LOAD_OPTIONS`), its models merged in order: a model ends where `o` or `g`
/// follows faces, or a `usemtl` naming another material does; within a model each
/// distinct (vertex, texture coordinate, normal) reference becomes one vertex, in the order
/// of first use; a face of n vertices is the fan (1, k, k + 1) for k = 2..n−1. Normals are
/// kept where every face vertex has one. Materials are `tobj`'s, from the canonical MTL
/// text, merged per `mtllib` as `tobj` merges them.
struct ObjParser<'a> {
    path: &'a Path,
    dir: PathBuf,
    files: &'a dyn FileSource,
    limits: &'a Limits,
    warnings: Vec<String>,
    nvt: u64,
    triangles: u64,
    refs_with_normal: u64,
    refs_without_normal: u64,
    /// Canonical text of each MTL file read, by path.
    mtl_texts: HashMap<PathBuf, String>,
    ignored: HashMap<&'static str, (usize, usize)>,
    /// The materials of every `mtllib` so far, and each name's index (the last definition
    /// of a name wins).
    materials: Vec<tobj::Material>,
    material_ids: HashMap<String, usize>,
    /// A failed MTL parse (reported where no material was read at all).
    mtl_error: Option<tobj::LoadError>,
    /// `mtllib` files that are absent: warned about, their materials the default.
    missing_mtl: Vec<PathBuf>,
    /// Every `v` and `vn` so far.
    points: Vec<Vec3>,
    point_normals: Vec<Vec3>,
    /// The mesh: positions, normals (while every face vertex so far has one), triangles.
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    indices: Vec<[u32; 3]>,
    /// Per mesh vertex its texture coordinate and normal (`NONE`: none), from the first face
    /// vertex that names either on (before, every vertex has neither).
    corners: Vec<[u32; 2]>,
    with_corners: bool,
    /// Per `v`: the mesh vertex first made of it in the current model (where that is at
    /// least `model_first_vertex`), and the model's other vertices made of a `v` by their
    /// whole reference.
    first_use: Vec<u32>,
    other_uses: HashMap<[u32; 3], u32>,
    /// The ended models: their first triangle and material.
    models: Vec<(usize, Option<usize>)>,
    model_first_vertex: u32,
    model_first_triangle: usize,
    model_material: Option<usize>,
}

impl<'a> ObjParser<'a> {
    fn new(path: &'a Path, files: &'a dyn FileSource, limits: &'a Limits) -> Self {
        Self {
            path,
            dir: path.parent().unwrap_or(Path::new("")).to_path_buf(),
            files,
            limits,
            warnings: Vec::new(),
            nvt: 0,
            triangles: 0,
            refs_with_normal: 0,
            refs_without_normal: 0,
            mtl_texts: HashMap::new(),
            ignored: HashMap::new(),
            materials: Vec::new(),
            material_ids: HashMap::new(),
            mtl_error: None,
            missing_mtl: Vec::new(),
            points: Vec::new(),
            point_normals: Vec::new(),
            positions: Vec::new(),
            normals: Vec::new(),
            indices: Vec::new(),
            corners: Vec::new(),
            with_corners: false,
            first_use: Vec::new(),
            other_uses: HashMap::new(),
            models: Vec::new(),
            model_first_vertex: 0,
            model_first_triangle: 0,
            model_material: None,
        }
    }

    fn ignore(&mut self, what: &'static str, ln: usize) {
        let e = self.ignored.entry(what).or_insert((ln, 0));
        e.1 += 1;
    }

    /// Ends the current model where it has faces.
    fn end_model(&mut self) {
        if self.indices.len() > self.model_first_triangle {
            self.models
                .push((self.model_first_triangle, self.model_material));
            self.model_first_triangle = self.indices.len();
            self.model_first_vertex = self.positions.len() as u32;
            self.other_uses.clear();
        }
    }

    /// The mesh vertex of a face vertex (1-based indices, checked), made where the model
    /// has none of that reference yet.
    fn vertex(&mut self, v: u64, vt: Option<u64>, vn: Option<u64>) -> u32 {
        let v = (v - 1) as usize;
        let corner = [
            vt.map_or(NONE, |i| (i - 1) as u32),
            vn.map_or(NONE, |i| (i - 1) as u32),
        ];
        if corner != [NONE; 2] && !self.with_corners {
            self.corners.resize(self.positions.len(), [NONE; 2]);
            self.with_corners = true;
        }
        let corner_of = |k: u32| match self.with_corners {
            true => self.corners[k as usize],
            false => [NONE; 2],
        };
        let first = self.first_use[v];
        let first_here = first != NONE && first >= self.model_first_vertex;
        if first_here && corner_of(first) == corner {
            return first;
        }
        let key = [v as u32, corner[0], corner[1]];
        if first_here {
            if let Some(&k) = self.other_uses.get(&key) {
                return k;
            }
        }
        let k = self.positions.len() as u32;
        self.positions.push(self.points[v]);
        if self.refs_without_normal == 0 {
            if let Some(n) = vn {
                self.normals.push(self.point_normals[(n - 1) as usize]);
            }
        }
        if self.with_corners {
            self.corners.push(corner);
        }
        if first_here {
            self.other_uses.insert(key, k);
        } else {
            self.first_use[v] = k;
        }
        k
    }

    fn line(&mut self, ln: usize, raw: &str) -> Result<(), SceneError> {
        let path = self.path;
        let limits = self.limits;
        let Some((kw, args, rest)) = split_line(raw) else {
            return Ok(());
        };
        if kw.starts_with('#') {
            return Ok(());
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
                let nv = self.points.len() as u64 + 1;
                if nv > limits.max_vertices {
                    return Err(SceneError::TooLarge {
                        origin: Origin::line(path, ln),
                        what: "vertex",
                        count: nv,
                        limit: limits.max_vertices,
                    });
                }
                self.points.push(p);
                self.first_use.push(NONE);
            }
            "vt" => {
                let v = parse_all(&args, path, ln, "vt")?;
                if !(1..=3).contains(&v.len()) {
                    return Err(err_line(
                        path,
                        ln,
                        format!("`vt` needs 1 to 3 numbers, found {}", v.len()),
                    ));
                }
                self.nvt += 1;
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
                self.point_normals.push(Vec3::new(*x, *y, *z));
            }
            "f" | "fo" => self.face(ln, &args)?,
            "o" | "g" => self.end_model(),
            "usemtl" => {
                if rest.is_empty() {
                    return Err(err_line(path, ln, "`usemtl` needs a material name"));
                }
                let known = self.material_ids.get(rest).copied();
                if known.is_none() && !self.missing_mtl.is_empty() {
                    // Possibly a material of the missing library: the default, as loaders
                    // do, with a warning.
                    self.warnings.push(format!(
                        "{}:{ln}: material `{rest}` is in no library read (one is missing): \
                         the default material",
                        path.display()
                    ));
                    if self.model_material.is_some() {
                        self.end_model();
                    }
                    self.model_material = None;
                    return Ok(());
                }
                let Some(id) = known else {
                    let hint = if self.mtl_texts.is_empty() && self.missing_mtl.is_empty() {
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
                };
                if self.model_material != Some(id) {
                    self.end_model();
                }
                self.model_material = Some(id);
            }
            "mtllib" => {
                if rest.is_empty() {
                    return Err(err_line(path, ln, "`mtllib` needs a file name"));
                }
                // One file whose name may contain spaces, or several names.
                let whole = self.dir.join(rest);
                let names: Vec<&str> = if args.len() > 1
                    && self.files.read_text(&whole, limits.max_file_bytes).is_err()
                {
                    args.clone()
                } else {
                    vec![rest]
                };
                for name in names {
                    let full = self.dir.join(name);
                    if !self.mtl_texts.contains_key(&full) && !self.files.exists(&full) {
                        // As OBJ loaders do (tobj, Assimp, Blender): a missing library is a
                        // warning, and the materials it would define are the default.
                        self.warnings.push(format!(
                            "{}:{ln}: mtllib `{}` not found: its materials are the default",
                            path.display(),
                            full.display()
                        ));
                        if !self.missing_mtl.contains(&full) {
                            self.missing_mtl.push(full);
                        }
                        continue;
                    }
                    if !self.mtl_texts.contains_key(&full) {
                        let mtl = self.files.read_text(&full, limits.max_file_bytes)?;
                        let checked = check_mtl(&mtl, &full)?;
                        self.warnings.extend(checked.warnings);
                        self.mtl_texts.insert(full.clone(), checked.canonical);
                    }
                    // Each naming adds the file's materials again (as `tobj` merges them).
                    match tobj::load_mtl_buf(&mut self.mtl_texts[&full].as_bytes()) {
                        Ok((mut materials, ids)) => {
                            let offset = self.materials.len();
                            self.materials.append(&mut materials);
                            self.material_ids
                                .extend(ids.into_iter().map(|(n, k)| (n, k + offset)));
                        }
                        Err(e) => self.mtl_error = Some(e),
                    }
                }
            }
            "l" => self.ignore("l (polyline)", ln),
            "p" => self.ignore("p (point)", ln),
            "s" => self.ignore("s (smoothing group)", ln),
            "vp" | "cstype" | "deg" | "bmat" | "step" | "curv" | "curv2" | "surf" | "parm"
            | "trim" | "hole" | "scrv" | "sp" | "end" | "con" => {
                self.ignore("free-form geometry", ln)
            }
            "mg" | "bevel" | "c_interp" | "d_interp" | "lod" | "usemap" | "maplib"
            | "shadow_obj" | "trace_obj" | "ctech" | "stech" => self.ignore("render attribute", ln),
            _ => {
                return Err(err_line(path, ln, format!("unknown OBJ statement `{kw}`")));
            }
        }
        Ok(())
    }

    /// A face: its references checked against what was defined before it, then its fan of
    /// triangles added.
    fn face(&mut self, ln: usize, args: &[&str]) -> Result<(), SceneError> {
        let path = self.path;
        if args.len() < 3 {
            return Err(err_line(
                path,
                ln,
                format!("a face needs at least 3 vertices, found {}", args.len()),
            ));
        }
        let counts = [
            self.points.len() as u64,
            self.nvt,
            self.point_normals.len() as u64,
        ];
        let mut refs: Vec<[Option<u64>; 3]> = Vec::with_capacity(args.len());
        for tok in args {
            let parts: Vec<&str> = tok.split('/').collect();
            if parts.len() > 3 || parts[0].is_empty() {
                return Err(err_line(
                    path,
                    ln,
                    format!("`{tok}` is not a face vertex (v, v/vt, v//vn or v/vt/vn)"),
                ));
            }
            let mut r = [None; 3];
            let lists = ["vertex", "texture coordinate", "normal"];
            for (k, part) in parts.iter().enumerate() {
                if part.is_empty() {
                    continue;
                }
                let (what, count) = (lists[k], counts[k]);
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
                r[k] = Some(resolved as u64);
            }
            refs.push(r);
        }
        self.triangles += args.len() as u64 - 2;
        if self.triangles > self.limits.max_triangles {
            return Err(SceneError::TooLarge {
                origin: Origin::line(path, ln),
                what: "triangle",
                count: self.triangles,
                limit: self.limits.max_triangles,
            });
        }
        for r in &refs {
            if r[2].is_some() {
                self.refs_with_normal += 1;
            } else {
                self.refs_without_normal += 1;
            }
        }
        if self.refs_without_normal > 0 {
            self.normals = Vec::new();
        }
        // The fan (1, k, k + 1); `tobj` looks the first corner up again for each triangle,
        // which finds the vertex it made.
        let vertex =
            |obj: &mut Self, [v, vt, vn]: [Option<u64>; 3]| obj.vertex(v.unwrap_or(1), vt, vn);
        let a = vertex(self, refs[0]);
        let mut b = vertex(self, refs[1]);
        for &r in &refs[2..] {
            let c = vertex(self, r);
            self.indices.push([a, b, c]);
            b = c;
        }
        Ok(())
    }

    /// The mesh, its materials and the warnings.
    fn finish(mut self) -> Result<ObjMesh, SceneError> {
        let path = self.path;
        // The last model, with or without faces (as `tobj` ends it).
        self.models
            .push((self.model_first_triangle, self.model_material));
        let mut ignored: Vec<_> = std::mem::take(&mut self.ignored).into_iter().collect();
        ignored.sort();
        for (what, (first, n)) in ignored {
            if what != "s (smoothing group)" {
                self.warnings.push(format!(
                    "{}:{first}: ignored {n} `{what}` statement{}",
                    path.display(),
                    if n == 1 { "" } else { "s" }
                ));
            }
        }
        if self.materials.is_empty() {
            if let Some(e) = self.mtl_error.take() {
                return Err(SceneError::syntax(
                    Origin::file(path),
                    format!(
                        "tobj rejected the file after validation ({e}); this is a vkrt bug, \
                         please report it"
                    ),
                ));
            }
        }
        drop(std::mem::take(&mut self.points));
        drop(std::mem::take(&mut self.point_normals));
        drop(std::mem::take(&mut self.first_use));
        drop(std::mem::take(&mut self.corners));
        drop(std::mem::take(&mut self.other_uses));

        let mut materials: Vec<Material> = self.materials.iter().map(material_from_mtl).collect();
        let mut default_id: Option<MaterialId> = None;
        let n_tris = self.indices.len();
        // Per model its material and triangles (`tobj`'s models, in order).
        let mut runs: Vec<(MaterialId, usize)> = Vec::with_capacity(self.models.len());
        for (i, &(first, id)) in self.models.iter().enumerate() {
            let end = self.models.get(i + 1).map_or(n_tris, |m| m.0);
            let material = match id {
                Some(id) if id < materials.len() => id as MaterialId,
                _ => *default_id.get_or_insert_with(|| {
                    materials.push(Material::default());
                    (materials.len() - 1) as MaterialId
                }),
            };
            runs.push((material, end - first));
        }
        let all_normals = self.refs_without_normal == 0 && self.refs_with_normal > 0;
        if !all_normals {
            if self.refs_with_normal > 0 {
                self.warnings.push(format!(
                    "{}: only some face vertices have normals; using face normals everywhere",
                    path.display()
                ));
            }
            self.normals = Vec::new();
        }
        if materials.is_empty() {
            materials.push(Material::default());
        }
        let mut used = runs.iter().filter(|r| r.1 > 0).map(|r| r.0);
        let single = used.next().unwrap_or(0);
        let materials_of_mesh = if used.all(|m| m == single) {
            MeshMaterials::Single(single)
        } else {
            let mut ids = Vec::with_capacity(n_tris);
            for (m, n) in runs {
                ids.extend(std::iter::repeat_n(m, n));
            }
            MeshMaterials::PerTriangle(ids.into())
        };
        let name = path
            .file_name()
            .map_or_else(|| "obj".to_owned(), |n| n.to_string_lossy().into_owned());
        self.positions.shrink_to_fit();
        self.indices.shrink_to_fit();
        self.normals.shrink_to_fit();
        let mut mesh = Mesh::new(&name, self.positions, self.indices, 0);
        mesh.normals = self.normals.into();
        mesh.materials = materials_of_mesh;
        Ok(ObjMesh {
            mesh,
            materials,
            warnings: self.warnings,
        })
    }
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
    scene_of(parse_obj_str(text, path, files, limits)?, path, limits)
}

/// [`load_obj_scene`] of the file at `path`, read line by line ([`parse_obj_file`]).
pub fn load_obj_scene_file(
    path: &Path,
    files: &dyn FileSource,
    limits: &Limits,
) -> Result<LoadedScene, SceneError> {
    scene_of(parse_obj_file(path, files, limits)?, path, limits)
}

fn scene_of(obj: ObjMesh, path: &Path, limits: &Limits) -> Result<LoadedScene, SceneError> {
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
