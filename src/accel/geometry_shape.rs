//! Geometry described by its counts alone, without buffers: what
//! `vkGetAccelerationStructureBuildSizesKHR` reads of a `VkAccelerationStructureGeometryKHR`
//! (format, stride, vertex and primitive counts, index type; no addresses), and the formats
//! both forms share. A structure's
//! sizes depend on nothing else, so a caller sizes its memory before any geometry buffer
//! exists ([`AccelBuilder::sizes_for`](crate::accel::device::AccelBuilder::sizes_for) takes
//! either form: [`GeometryDescription`]).

use crate::gpu::{Context, GpuError, Result};

/// How vertex positions are stored (`VkFormat`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum VertexFormat {
    /// `VK_FORMAT_R32G32B32_SFLOAT`: three 32-bit floats (any trailing data up to the stride
    /// is ignored, so `R32G32B32A32` vertices work with a 16-byte stride).
    #[default]
    Rgb32Float,
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
        /// Bytes from one vertex to the next (a multiple of 4, at least 12).
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
                stride,
                vertex_count,
                index_type,
                triangle_count,
                ..
            } => {
                if stride < 12 || stride % 4 != 0 {
                    return err(format!(
                        "vertex stride {stride} (a multiple of 4, at least 12)"
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
