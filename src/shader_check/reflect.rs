//! What `vkrt shader-check` reads of a compiled shader before any GPU work: its compute
//! entry point's workgroup size, its descriptor bindings and their types, its push-constant
//! block's size, and its specialization constants: a minimal SPIR-V reader (the words of
//! the decorations and types it needs, nothing else).

use std::collections::HashMap;

const MAGIC: u32 = 0x0723_0203;

// Opcodes.
const OP_NAME: u32 = 5;
const OP_ENTRY_POINT: u32 = 15;
const OP_EXECUTION_MODE: u32 = 16;
const OP_TYPE_INT: u32 = 21;
const OP_TYPE_FLOAT: u32 = 22;
const OP_TYPE_VECTOR: u32 = 23;
const OP_TYPE_MATRIX: u32 = 24;
const OP_TYPE_IMAGE: u32 = 25;
const OP_TYPE_SAMPLED_IMAGE: u32 = 27;
const OP_TYPE_ARRAY: u32 = 28;
const OP_TYPE_RUNTIME_ARRAY: u32 = 29;
const OP_TYPE_STRUCT: u32 = 30;
const OP_TYPE_POINTER: u32 = 32;
const OP_CONSTANT: u32 = 43;
const OP_CONSTANT_COMPOSITE: u32 = 44;
const OP_SPEC_CONSTANT: u32 = 50;
const OP_SPEC_CONSTANT_COMPOSITE: u32 = 51;
const OP_VARIABLE: u32 = 59;
const OP_DECORATE: u32 = 71;
const OP_MEMBER_DECORATE: u32 = 72;
const OP_EXECUTION_MODE_ID: u32 = 331;
const OP_TYPE_ACCELERATION_STRUCTURE: u32 = 5341;
const OP_CAPABILITY: u32 = 17;

// Decorations, execution modes, storage classes, built-ins.
const DEC_SPEC_ID: u32 = 1;
const DEC_BUFFER_BLOCK: u32 = 3;
const DEC_ARRAY_STRIDE: u32 = 6;
const DEC_BUILTIN: u32 = 11;
const DEC_BINDING: u32 = 33;
const DEC_DESCRIPTOR_SET: u32 = 34;
const DEC_OFFSET: u32 = 35;
const MODE_LOCAL_SIZE: u32 = 17;
const MODE_LOCAL_SIZE_ID: u32 = 38;
const MODEL_GL_COMPUTE: u32 = 5;
const STORAGE_UNIFORM_CONSTANT: u32 = 0;
const STORAGE_UNIFORM: u32 = 2;
const STORAGE_PUSH_CONSTANT: u32 = 9;
const STORAGE_STORAGE_BUFFER: u32 = 12;
const BUILTIN_WORKGROUP_SIZE: u32 = 25;
const DIM_BUFFER: u32 = 5;
const CAPABILITY_RAY_QUERY: u32 = 4472;

/// What a descriptor binding holds, as the shader declares it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    /// `accelerationStructureEXT`.
    AccelerationStructure,
    /// A sampled buffer image (`usamplerBuffer`, `textureBuffer`): a uniform texel buffer.
    UniformTexelBuffer,
    /// A buffer block (`buffer`): a storage buffer; `vec4_array`: its last member is a
    /// runtime array of four 32-bit components (16 bytes an element).
    StorageBuffer {
        /// Whether its last member is an array of 16-byte four-component vectors.
        vec4_array: bool,
    },
    /// Anything else (a uniform block, an image, a sampler...).
    Other(&'static str),
}

impl BindingKind {
    /// In words, for messages.
    pub fn describe(&self) -> String {
        match self {
            BindingKind::AccelerationStructure => "an accelerationStructureEXT".into(),
            BindingKind::UniformTexelBuffer => "a uniform texel buffer".into(),
            BindingKind::StorageBuffer { vec4_array: true } => {
                "a storage buffer of 16-byte vectors".into()
            }
            BindingKind::StorageBuffer { vec4_array: false } => {
                "a storage buffer whose last member is not an array of 4-component 32-bit \
                 vectors"
                    .into()
            }
            BindingKind::Other(what) => (*what).into(),
        }
    }
}

/// One descriptor the shader declares.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Binding {
    /// Its set and binding.
    pub set: u32,
    /// Its binding number.
    pub binding: u32,
    /// What it holds.
    pub kind: BindingKind,
    /// Its name in the source, where the module keeps names.
    pub name: Option<String>,
}

/// What the command needs to know of a compiled compute shader.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ShaderInterface {
    /// Whether the module has a `GLCompute` entry point named `main`.
    pub compute_main: bool,
    /// Its workgroup size (after default specialization), where declared.
    pub local_size: Option<[u32; 3]>,
    /// Every descriptor it declares.
    pub bindings: Vec<Binding>,
    /// Bytes of its push-constant block (`None`: it has none), and whether the block's first
    /// member (at offset 0) is a 32-bit integer.
    pub push_constants: Option<(u32, bool)>,
    /// Its specialization constants' ids.
    pub spec_ids: Vec<u32>,
    /// Whether it declares the `RayQueryKHR` capability (the driver's ray query).
    pub uses_ray_query: bool,
    /// For a two-dimensional workgroup: the width of the image the rays cover (the
    /// caller's, not the module's: `vkrt shader-check --width`), which the shader reads as
    /// its push block's second word.
    pub grid_width: Option<u32>,
}

/// Why the words are not a SPIR-V module this reader can follow.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("not a SPIR-V module: {0}")]
pub struct NotSpirv(pub String);

#[derive(Clone, Debug)]
enum Type {
    Int(u32),
    Float(u32),
    Vector(u32, u32),
    Matrix(u32, u32),
    Array(u32, u32),
    RuntimeArray(u32),
    Struct(Vec<u32>),
    Pointer(u32),
    Image { dim: u32, sampled: u32 },
    SampledImage(u32),
    Accel,
}

/// Reads `words` (a SPIR-V module).
pub fn reflect(words: &[u32]) -> Result<ShaderInterface, NotSpirv> {
    if words.len() < 5 || words[0] != MAGIC {
        return Err(NotSpirv("no SPIR-V header".into()));
    }
    let mut types: HashMap<u32, Type> = HashMap::new();
    let mut constants: HashMap<u32, u32> = HashMap::new();
    let mut composites: HashMap<u32, Vec<u32>> = HashMap::new();
    let mut names: HashMap<u32, String> = HashMap::new();
    let mut sets: HashMap<u32, u32> = HashMap::new();
    let mut binding_of: HashMap<u32, u32> = HashMap::new();
    let mut spec_id: HashMap<u32, u32> = HashMap::new();
    let mut buffer_block: Vec<u32> = Vec::new();
    let mut builtin_size: Option<u32> = None;
    let mut offsets: HashMap<(u32, u32), u32> = HashMap::new();
    let mut strides: HashMap<u32, u32> = HashMap::new();
    let mut variables: Vec<(u32, u32, u32)> = Vec::new();
    let mut entry: Option<u32> = None;
    let mut local_size: Option<[u32; 3]> = None;
    let mut local_size_ids: Option<[u32; 3]> = None;
    let mut uses_ray_query = false;
    let mut at = 5;
    while at < words.len() {
        let count = (words[at] >> 16) as usize;
        let op = words[at] & 0xffff;
        if count == 0 || at + count > words.len() {
            return Err(NotSpirv(format!("a truncated instruction at word {at}")));
        }
        let w = &words[at + 1..at + count];
        let arg = |k: usize| w.get(k).copied().unwrap_or(0);
        match op {
            OP_CAPABILITY if arg(0) == CAPABILITY_RAY_QUERY => uses_ray_query = true,
            OP_NAME => {
                names.insert(arg(0), string_of(&w[1.min(w.len())..]));
            }
            OP_ENTRY_POINT if arg(0) == MODEL_GL_COMPUTE && string_of(&w[2..]) == "main" => {
                entry = Some(arg(1));
            }
            OP_EXECUTION_MODE | OP_EXECUTION_MODE_ID if w.len() >= 5 => match arg(1) {
                MODE_LOCAL_SIZE if Some(arg(0)) == entry => {
                    local_size = Some([arg(2), arg(3), arg(4)])
                }
                MODE_LOCAL_SIZE_ID if Some(arg(0)) == entry => {
                    local_size_ids = Some([arg(2), arg(3), arg(4)])
                }
                _ => {}
            },
            OP_DECORATE => match arg(1) {
                DEC_DESCRIPTOR_SET => {
                    sets.insert(arg(0), arg(2));
                }
                DEC_BINDING => {
                    binding_of.insert(arg(0), arg(2));
                }
                DEC_SPEC_ID => {
                    spec_id.insert(arg(0), arg(2));
                }
                DEC_BUFFER_BLOCK => buffer_block.push(arg(0)),
                DEC_ARRAY_STRIDE => {
                    strides.insert(arg(0), arg(2));
                }
                DEC_BUILTIN if arg(2) == BUILTIN_WORKGROUP_SIZE => builtin_size = Some(arg(0)),
                _ => {}
            },
            OP_MEMBER_DECORATE if arg(2) == DEC_OFFSET => {
                offsets.insert((arg(0), arg(1)), arg(3));
            }
            OP_TYPE_INT => {
                types.insert(arg(0), Type::Int(arg(1)));
            }
            OP_TYPE_FLOAT => {
                types.insert(arg(0), Type::Float(arg(1)));
            }
            OP_TYPE_VECTOR => {
                types.insert(arg(0), Type::Vector(arg(1), arg(2)));
            }
            OP_TYPE_MATRIX => {
                types.insert(arg(0), Type::Matrix(arg(1), arg(2)));
            }
            OP_TYPE_IMAGE => {
                types.insert(
                    arg(0),
                    Type::Image {
                        dim: arg(2),
                        sampled: arg(6),
                    },
                );
            }
            OP_TYPE_SAMPLED_IMAGE => {
                types.insert(arg(0), Type::SampledImage(arg(1)));
            }
            OP_TYPE_ARRAY => {
                types.insert(arg(0), Type::Array(arg(1), arg(2)));
            }
            OP_TYPE_RUNTIME_ARRAY => {
                types.insert(arg(0), Type::RuntimeArray(arg(1)));
            }
            OP_TYPE_STRUCT => {
                types.insert(arg(0), Type::Struct(w[1..].to_vec()));
            }
            OP_TYPE_POINTER => {
                types.insert(arg(0), Type::Pointer(arg(2)));
            }
            OP_TYPE_ACCELERATION_STRUCTURE => {
                types.insert(arg(0), Type::Accel);
            }
            OP_CONSTANT | OP_SPEC_CONSTANT => {
                constants.insert(arg(1), arg(2));
            }
            OP_CONSTANT_COMPOSITE | OP_SPEC_CONSTANT_COMPOSITE => {
                composites.insert(arg(1), w[2..].to_vec());
            }
            OP_VARIABLE => variables.push((arg(0), arg(1), arg(2))),
            _ => {}
        }
        at += count;
    }
    let mut out = ShaderInterface {
        compute_main: entry.is_some(),
        uses_ray_query,
        ..Default::default()
    };
    // The workgroup size: the WorkgroupSize built-in wins over the execution mode.
    let constant = |id: u32| constants.get(&id).copied();
    out.local_size = match builtin_size.and_then(|id| composites.get(&id)) {
        Some(parts) if parts.len() == 3 => {
            let v: Option<Vec<u32>> = parts.iter().map(|&p| constant(p)).collect();
            v.map(|v| [v[0], v[1], v[2]])
        }
        _ => local_size.or_else(|| {
            let ids = local_size_ids?;
            Some([constant(ids[0])?, constant(ids[1])?, constant(ids[2])?])
        }),
    };
    let size_of = |t: u32| size_of(&types, &constants, &offsets, &strides, t, 0);
    for &(pointer, id, class) in &variables {
        let Some(Type::Pointer(pointee)) = types.get(&pointer) else {
            continue;
        };
        let pointee = *pointee;
        if class == STORAGE_PUSH_CONSTANT {
            let bytes = size_of(pointee).unwrap_or(0);
            // The first word, through structs nested at offset 0 (naga wraps a WGSL push
            // constant struct in a block of its own).
            let mut first = pointee;
            let mut first_is_u32 = false;
            for _ in 0..8 {
                match types.get(&first) {
                    Some(Type::Struct(members))
                        if !members.is_empty() && offsets.get(&(first, 0)).copied() == Some(0) =>
                    {
                        first = members[0];
                    }
                    Some(Type::Int(32)) => {
                        first_is_u32 = first != pointee;
                        break;
                    }
                    _ => break,
                }
            }
            out.push_constants = Some((bytes, first_is_u32));
            continue;
        }
        if !matches!(
            class,
            STORAGE_UNIFORM_CONSTANT | STORAGE_UNIFORM | STORAGE_STORAGE_BUFFER
        ) {
            continue;
        }
        let (Some(&set), Some(&binding)) = (sets.get(&id), binding_of.get(&id)) else {
            continue;
        };
        // An array of descriptors is reported as its element with the array noted.
        let (inner, arrayed) = match types.get(&pointee) {
            Some(Type::Array(e, _) | Type::RuntimeArray(e)) => (*e, true),
            _ => (pointee, false),
        };
        let kind = match (class, types.get(&inner)) {
            _ if arrayed => BindingKind::Other("an array of descriptors"),
            (STORAGE_UNIFORM_CONSTANT, Some(Type::Accel)) => BindingKind::AccelerationStructure,
            (STORAGE_UNIFORM_CONSTANT, Some(Type::SampledImage(image))) => {
                image_kind(types.get(image))
            }
            (STORAGE_UNIFORM_CONSTANT, Some(t @ Type::Image { .. })) => image_kind(Some(t)),
            (STORAGE_STORAGE_BUFFER, Some(Type::Struct(members))) => BindingKind::StorageBuffer {
                vec4_array: last_is_vec4_array(&types, members),
            },
            (STORAGE_UNIFORM, Some(Type::Struct(members))) if buffer_block.contains(&inner) => {
                BindingKind::StorageBuffer {
                    vec4_array: last_is_vec4_array(&types, members),
                }
            }
            (STORAGE_UNIFORM, _) => BindingKind::Other("a uniform block"),
            _ => BindingKind::Other("a sampler or image"),
        };
        out.bindings.push(Binding {
            set,
            binding,
            kind,
            // A block without an instance name is known by its type's name.
            name: [id, inner]
                .iter()
                .find_map(|k| names.get(k).filter(|n| !n.is_empty()))
                .cloned(),
        });
    }
    out.bindings.sort_by_key(|b| (b.set, b.binding));
    out.spec_ids = spec_id.into_values().collect();
    out.spec_ids.sort_unstable();
    Ok(out)
}

/// A sampled buffer image is a uniform texel buffer; other images are not.
fn image_kind(t: Option<&Type>) -> BindingKind {
    match t {
        Some(Type::Image {
            dim: DIM_BUFFER,
            sampled: 1,
        }) => BindingKind::UniformTexelBuffer,
        Some(Type::Image {
            dim: DIM_BUFFER, ..
        }) => BindingKind::Other("a storage texel buffer"),
        _ => BindingKind::Other("an image"),
    }
}

fn last_is_vec4_array(types: &HashMap<u32, Type>, members: &[u32]) -> bool {
    let Some(Type::RuntimeArray(e)) = members.last().and_then(|m| types.get(m)) else {
        return false;
    };
    match types.get(e) {
        Some(Type::Vector(c, 4)) => {
            matches!(types.get(c), Some(Type::Int(32) | Type::Float(32)))
        }
        _ => false,
    }
}

/// Bytes of type `t` as laid out in a block (explicit offsets and strides; `None` where
/// unknown or unbounded).
fn size_of(
    types: &HashMap<u32, Type>,
    constants: &HashMap<u32, u32>,
    offsets: &HashMap<(u32, u32), u32>,
    strides: &HashMap<u32, u32>,
    t: u32,
    depth: u32,
) -> Option<u32> {
    if depth > 32 {
        return None;
    }
    let rec = |t: u32| size_of(types, constants, offsets, strides, t, depth + 1);
    match types.get(&t)? {
        Type::Int(bits) | Type::Float(bits) => Some(bits / 8),
        Type::Vector(c, n) => Some(rec(*c)? * n),
        Type::Matrix(col, n) => Some(rec(*col)? * n),
        Type::Array(e, len) => {
            let stride = strides.get(&t).copied().or_else(|| rec(*e))?;
            Some(stride * constants.get(len)?)
        }
        Type::Struct(members) => {
            let mut end = 0;
            for (k, &m) in members.iter().enumerate() {
                let off = offsets.get(&(t, k as u32)).copied()?;
                end = end.max(off + rec(m)?);
            }
            Some(end)
        }
        _ => None,
    }
}

/// A literal string (nul-terminated, four bytes a word, little-endian).
fn string_of(words: &[u32]) -> String {
    let bytes: Vec<u8> = words
        .iter()
        .flat_map(|w| w.to_le_bytes())
        .take_while(|&b| b != 0)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_what_is_not_spirv() {
        assert!(reflect(&[1, 2, 3]).is_err());
        assert!(reflect(&[MAGIC, 0x10500, 0, 100, 0, 0x0005_0047]).is_err());
    }

    #[test]
    fn strings_stop_at_nul() {
        let w = u32::from_le_bytes(*b"main");
        assert_eq!(string_of(&[w, 0]), "main");
        assert_eq!(string_of(&[u32::from_le_bytes([b'a', 0, b'x', b'y'])]), "a");
    }
}
