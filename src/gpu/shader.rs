//! The SPIR-V of every kernel in `glsl/`, compiled by `build.rs`, with the interface
//! reflected from the SPIR-V itself (bindings, specialization constants, workgroup size).

/// One compiled kernel variant.
#[derive(Debug)]
pub struct ShaderBlob {
    /// `dir.file[.variant]`, e.g. `gpu.saxpy`; also the default pass label.
    pub name: &'static str,
    /// The source file, relative to the crate root.
    pub source: &'static str,
    /// Macro definitions of this variant.
    pub defines: &'static [(&'static str, &'static str)],
    /// Bindings of descriptor set 0, ascending: storage buffers, and the uniform texel
    /// buffers among them listed in `texel_bindings`.
    pub bindings: &'static [u32],
    /// Of `bindings`, the uniform texel buffers (read as RGBA32UI texels).
    pub texel_bindings: &'static [u32],
    /// Of `bindings`, those the kernel only reads (`readonly` blocks and texel buffers).
    pub read_only_bindings: &'static [u32],
    /// Of `bindings`, those the kernel only writes (`writeonly` blocks).
    pub write_only_bindings: &'static [u32],
    /// `(constant_id, default value bits)` of every specialization constant.
    pub spec_constants: &'static [(u32, u32)],
    /// Default workgroup size.
    pub local_size: [u32; 3],
    /// Specialization constant ids that set the workgroup size, per axis.
    pub local_size_spec_ids: [Option<u32>; 3],
    /// Whether the kernel declares a push-constant block.
    pub push_constants: bool,
    /// The SPIR-V module, as 32-bit words.
    pub spirv: &'static [u32],
}

/// The generated table: one `pub static` per kernel variant and `ALL`.
pub mod kernels {
    use super::ShaderBlob;
    include!(concat!(env!("OUT_DIR"), "/shaders.rs"));
}

/// Looks a kernel up by name (for tools; code should use the `kernels::` constants).
pub fn find(name: &str) -> Option<&'static ShaderBlob> {
    kernels::ALL.iter().copied().find(|b| b.name == name)
}
