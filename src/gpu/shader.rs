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

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use rspirv::dr::Operand;
    use rspirv::spirv::{Decoration, Op};

    /// The (set, binding) of every variable decorated with both, by variable id.
    fn bindings(module: &rspirv::dr::Module) -> HashMap<u32, (u32, u32)> {
        let mut set = HashMap::new();
        let mut binding = HashMap::new();
        for d in &module.annotations {
            let (Some(Operand::IdRef(target)), Some(Operand::Decoration(what))) =
                (d.operands.first(), d.operands.get(1))
            else {
                continue;
            };
            let Some(Operand::LiteralBit32(n)) = d.operands.get(2) else {
                continue;
            };
            match what {
                Decoration::DescriptorSet => set.insert(*target, *n),
                Decoration::Binding => binding.insert(*target, *n),
                _ => None,
            };
        }
        binding
            .into_iter()
            .filter_map(|(v, b)| Some((v, (*set.get(&v)?, b))))
            .collect()
    }

    /// One block (or image) type per binding in every kernel: SPIR-V's translators
    /// (SPIRV-Cross, naga) and stricter validators refuse variables of different types
    /// aliasing one binding, as the walks' nodes once did.
    #[test]
    fn every_kernel_declares_one_type_per_binding() {
        for blob in super::kernels::ALL {
            let module = rspirv::dr::load_words(blob.spirv).expect("a kernel's SPIR-V parses");
            let pointee: HashMap<u32, u32> = module
                .types_global_values
                .iter()
                .filter(|i| i.class.opcode == Op::TypePointer)
                .filter_map(|i| match (i.result_id, i.operands.get(1)) {
                    (Some(id), Some(Operand::IdRef(t))) => Some((id, *t)),
                    _ => None,
                })
                .collect();
            let mut types: HashMap<(u32, u32), u32> = HashMap::new();
            let decorated = bindings(&module);
            for v in module
                .types_global_values
                .iter()
                .filter(|i| i.class.opcode == Op::Variable)
            {
                let (Some(id), Some(ty)) = (v.result_id, v.result_type) else {
                    continue;
                };
                let Some(&at) = decorated.get(&id) else {
                    continue;
                };
                let ty = pointee.get(&ty).copied().unwrap_or(ty);
                let first = *types.entry(at).or_insert(ty);
                assert_eq!(
                    first, ty,
                    "{}: set {} binding {} is declared with two types",
                    blob.name, at.0, at.1
                );
            }
        }
    }
}
