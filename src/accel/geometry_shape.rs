//! Geometry described by its counts alone, without buffers: what
//! `vkGetAccelerationStructureBuildSizesKHR` reads of a `VkAccelerationStructureGeometryKHR`
//! (format, stride, vertex and primitive counts, index type; no addresses), and the formats
//! both forms share. A structure's
//! sizes depend on nothing else, so a caller sizes its memory before any geometry buffer
//! exists ([`AccelBuilder::sizes_for`](crate::accel::device::AccelBuilder::sizes_for) takes
//! either form: [`GeometryDescription`]).

use crate::gpu::{Context, GpuError, Result};

/// How vertex positions are stored (`VkFormat`): the six formats
/// `VK_KHR_acceleration_structure` requires of every device. A format without a z component
/// gives z = 0; a fourth component is ignored (as is any trailing data up to the stride, so
/// `R32G32B32A32` vertices work as `Rgb32Float` with a 16-byte stride).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum VertexFormat {
    /// `VK_FORMAT_R32G32B32_SFLOAT`: three 32-bit floats.
    #[default]
    Rgb32Float,
    /// `VK_FORMAT_R32G32_SFLOAT`: two 32-bit floats.
    Rg32Float,
    /// `VK_FORMAT_R16G16_SFLOAT`: two half floats.
    Rg16Float,
    /// `VK_FORMAT_R16G16B16A16_SFLOAT`: four half floats.
    Rgba16Float,
    /// `VK_FORMAT_R16G16_SNORM`: two signed 16-bit normalized values (`max(v / 32767, -1)`).
    Rg16Snorm,
    /// `VK_FORMAT_R16G16B16A16_SNORM`: four signed 16-bit normalized values.
    Rgba16Snorm,
}

impl VertexFormat {
    /// Bytes of one vertex: the least stride.
    pub fn bytes(self) -> u64 {
        match self {
            VertexFormat::Rgb32Float => 12,
            VertexFormat::Rg32Float | VertexFormat::Rgba16Float | VertexFormat::Rgba16Snorm => 8,
            VertexFormat::Rg16Float | VertexFormat::Rg16Snorm => 4,
        }
    }

    /// The format of `VkFormat` `raw`, if it is one of the six.
    pub fn from_vk(raw: ash::vk::Format) -> Option<Self> {
        use ash::vk::Format as F;
        Some(match raw {
            F::R32G32B32_SFLOAT => VertexFormat::Rgb32Float,
            F::R32G32_SFLOAT => VertexFormat::Rg32Float,
            F::R16G16_SFLOAT => VertexFormat::Rg16Float,
            F::R16G16B16A16_SFLOAT => VertexFormat::Rgba16Float,
            F::R16G16_SNORM => VertexFormat::Rg16Snorm,
            F::R16G16B16A16_SNORM => VertexFormat::Rgba16Snorm,
            _ => return None,
        })
    }

    /// The gather kernel's code for it (`FORMAT_*` in `accel/geometry_gather.comp`).
    pub(crate) fn code(self) -> u32 {
        match self {
            VertexFormat::Rgb32Float => 0,
            VertexFormat::Rg32Float => 1,
            VertexFormat::Rg16Float => 2,
            VertexFormat::Rgba16Float => 3,
            VertexFormat::Rg16Snorm => 4,
            VertexFormat::Rgba16Snorm => 5,
        }
    }

    /// The position of a vertex whose bytes start `v` (at least [`VertexFormat::bytes`]),
    /// as the gather kernel reads it.
    pub fn decode(self, v: &[u8]) -> [f32; 3] {
        let f32_at = |k: usize| f32::from_le_bytes(v[4 * k..4 * k + 4].try_into().unwrap());
        let u16_at = |k: usize| u16::from_le_bytes([v[2 * k], v[2 * k + 1]]);
        let half = |k: usize| half_to_f32(u16_at(k));
        let snorm = |k: usize| (f32::from(u16_at(k) as i16) / 32767.0).max(-1.0);
        match self {
            VertexFormat::Rgb32Float => [f32_at(0), f32_at(1), f32_at(2)],
            VertexFormat::Rg32Float => [f32_at(0), f32_at(1), 0.0],
            VertexFormat::Rg16Float => [half(0), half(1), 0.0],
            VertexFormat::Rgba16Float => [half(0), half(1), half(2)],
            VertexFormat::Rg16Snorm => [snorm(0), snorm(1), 0.0],
            VertexFormat::Rgba16Snorm => [snorm(0), snorm(1), snorm(2)],
        }
    }
}

/// An IEEE half's value (exact: every half is a float).
pub fn half_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exponent = u32::from((h >> 10) & 0x1f);
    let mantissa = u32::from(h & 0x3ff);
    let bits = match (exponent, mantissa) {
        (0, 0) => sign,
        // Subnormal: m · 2^-24, normalized.
        (0, m) => {
            let shift = m.leading_zeros() - 21;
            sign | ((113 - shift) << 23) | ((m << shift) & 0x3ff) << 13
        }
        (31, m) => sign | 0x7f80_0000 | (m << 13),
        (e, m) => sign | ((e + 112) << 23) | (m << 13),
    };
    f32::from_bits(bits)
}

/// The type of an index buffer's entries (`VkIndexType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum IndexType {
    /// `VK_INDEX_TYPE_UINT16`: 2-byte indices.
    U16,
    /// `VK_INDEX_TYPE_UINT32`: 4-byte indices.
    U32,
}

impl IndexType {
    pub(crate) fn bytes(self) -> u64 {
        match self {
            IndexType::U16 => 2,
            IndexType::U32 => 4,
        }
    }
}

/// In the structure's geometry table ([`GeometryLayout::table`](crate::accel::geometry::GeometryLayout::table)): the bit of the geometry
/// word that marks a non-opaque geometry (the ray query reads it; the index is the rest).
pub const NON_OPAQUE: u32 = 1 << 31;

/// One geometry of a structure, without its data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum GeometryShape {
    /// Triangles ([`crate::accel::geometry::Triangles`] without its buffers and transform).
    Triangles {
        /// How each vertex's position is stored.
        format: VertexFormat,
        /// Bytes from one vertex to the next (a multiple of 4, at least the format's bytes).
        stride: u64,
        /// Vertices the indices may name (`maxVertex + 1`).
        vertex_count: u32,
        /// `None`: non-indexed.
        index_type: Option<IndexType>,
        /// Triangles (`maxPrimitiveCount`).
        triangle_count: u32,
        /// `VK_GEOMETRY_OPAQUE_BIT_KHR`.
        opaque: bool,
    },
    /// Spheres, 16-byte records `stride` bytes apart.
    Spheres {
        /// At least 16, a multiple of 4.
        stride: u64,
        /// Spheres.
        count: u32,
        /// `VK_GEOMETRY_OPAQUE_BIT_KHR`.
        opaque: bool,
    },
    /// Axis-aligned boxes, 24-byte records `stride` bytes apart.
    Aabbs {
        /// At least 24, a multiple of 4.
        stride: u64,
        /// Boxes.
        count: u32,
        /// `VK_GEOMETRY_OPAQUE_BIT_KHR`.
        opaque: bool,
    },
}

impl GeometryShape {
    /// `triangle_count` opaque triangles over `vertex_count` tightly packed `vec3`s,
    /// indexed with `index_type` (`None`: a soup).
    pub fn triangles(
        vertex_count: u32,
        index_type: Option<IndexType>,
        triangle_count: u32,
    ) -> Self {
        GeometryShape::Triangles {
            format: VertexFormat::Rgb32Float,
            stride: 12,
            vertex_count,
            index_type,
            triangle_count,
            opaque: true,
        }
    }

    /// `count` opaque spheres, tightly packed.
    pub fn spheres(count: u32) -> Self {
        GeometryShape::Spheres {
            stride: 16,
            count,
            opaque: true,
        }
    }

    /// `count` opaque boxes, tightly packed.
    pub fn aabbs(count: u32) -> Self {
        GeometryShape::Aabbs {
            stride: 24,
            count,
            opaque: true,
        }
    }

    /// The same, opaque or not.
    pub fn with_opaque(mut self, value: bool) -> Self {
        match &mut self {
            GeometryShape::Triangles { opaque, .. }
            | GeometryShape::Spheres { opaque, .. }
            | GeometryShape::Aabbs { opaque, .. } => *opaque = value,
        }
        self
    }

    /// Its primitives.
    pub fn primitive_count(&self) -> u32 {
        match *self {
            GeometryShape::Triangles { triangle_count, .. } => triangle_count,
            GeometryShape::Spheres { count, .. } | GeometryShape::Aabbs { count, .. } => count,
        }
    }

    /// Whether its hits are opaque.
    pub fn opaque(&self) -> bool {
        match *self {
            GeometryShape::Triangles { opaque, .. }
            | GeometryShape::Spheres { opaque, .. }
            | GeometryShape::Aabbs { opaque, .. } => opaque,
        }
    }

    /// 0 triangles, 1 spheres, 2 boxes: the order of their ids.
    pub(crate) fn type_index(&self) -> usize {
        match self {
            GeometryShape::Triangles { .. } => 0,
            GeometryShape::Spheres { .. } => 1,
            GeometryShape::Aabbs { .. } => 2,
        }
    }

    /// Its word in the geometry table: geometry `index`, [`NON_OPAQUE`] where it is not.
    pub(crate) fn table_word(&self, index: usize) -> u32 {
        index as u32 | if self.opaque() { 0 } else { NON_OPAQUE }
    }

    /// Checks what the counts alone can say (strides; vertices for the triangles);
    /// `k`: its index in the list, for the message.
    pub(crate) fn check(&self, k: usize) -> Result<()> {
        let err = |what: String| {
            Err(GpuError::Usage {
                call: "accel geometry",
                reason: format!("geometry {k}: {what}"),
            })
        };
        match *self {
            GeometryShape::Triangles {
                format,
                stride,
                vertex_count,
                index_type,
                triangle_count,
                ..
            } => {
                if stride < format.bytes() || stride % 4 != 0 {
                    return err(format!(
                        "vertex stride {stride} (a multiple of 4, at least {} for {format:?})",
                        format.bytes()
                    ));
                }
                if triangle_count == 0 {
                    return Ok(());
                }
                if vertex_count == 0 {
                    return err("triangles over 0 vertices".into());
                }
                if index_type.is_none() && u64::from(triangle_count) * 3 > u64::from(vertex_count) {
                    return err(format!(
                        "{triangle_count} triangles without indices need {} vertices; \
                         {vertex_count} given",
                        3 * u64::from(triangle_count)
                    ));
                }
                Ok(())
            }
            GeometryShape::Spheres { stride, .. } => records_stride(k, "sphere", stride, 16),
            GeometryShape::Aabbs { stride, .. } => records_stride(k, "box", stride, 24),
        }
    }
}

fn records_stride(k: usize, what: &str, stride: u64, size: u64) -> Result<()> {
    if stride < size || stride % 4 != 0 {
        return Err(GpuError::Usage {
            call: "accel geometry",
            reason: format!(
                "geometry {k}: {what} stride {stride} (a multiple of 4, at least {size})"
            ),
        });
    }
    Ok(())
}

/// A geometry as sizes are asked for it: with its data
/// ([`Geometry`](crate::accel::geometry::Geometry), whose buffers are checked too) or by its
/// counts alone ([`GeometryShape`]).
pub trait GeometryDescription: Copy {
    /// What it is without its data.
    fn shape(&self) -> GeometryShape;
    /// Checks it against `ctx`'s device (`k`: its index in the list, for the message).
    fn check(&self, ctx: &Context, k: usize) -> Result<()>;
}

impl GeometryDescription for GeometryShape {
    fn shape(&self) -> GeometryShape {
        *self
    }

    fn check(&self, _: &Context, k: usize) -> Result<()> {
        GeometryShape::check(self, k)
    }
}
