//! The shader's side: queries become handles, structures become texel-buffer descriptors
//! and 64-bit addresses, and each ray-query instruction a call into the library.

use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{
    AddressingModel, Capability, Decoration, Dim, ImageFormat, Op, StorageClass, Word,
};
use std::collections::{BTreeSet, HashMap, HashSet};

use super::library::{decorates, Library};
use super::queries::{self, Handles};
use super::types::{Shape, Types};
use super::words::Scan;
use super::{LowerError, LowerOptions};

/// What the rewrite did.
pub(crate) struct Stats {
    pub query_states: u32,
    pub instructions: usize,
    pub structures: usize,
    /// The library functions the module now calls.
    pub used_functions: BTreeSet<Word>,
}

pub(crate) struct Rewriter<'m> {
    module: &'m mut Module,
    pub lib: Library,
    types: Types,
    /// Each of the shader's values' type.
    value_types: HashMap<Word, Word>,
    next_id: Word,
    rq: HashSet<Word>,
    accel: HashSet<Word>,
    nonuniform: HashSet<Word>,
    // Types and constants the rewrite uses, declared first.
    uint: Word,
    u64: Word,
    uvec2: Word,
    uvec4: Word,
    image: Word,
    zero: Word,
    invalid: Word,
    front: Vec<Instruction>,
    /// Constants for function-local initializers, declared last.
    back: Vec<Instruction>,
    handles: Handles,
    version: (u32, u32),
    stats: Stats,
}

/// A fresh instruction.
fn inst(op: Op, ty: Option<Word>, id: Option<Word>, operands: Vec<Operand>) -> Instruction {
    Instruction::new(op, ty, id, operands)
}

fn ids(v: &[Word]) -> Vec<Operand> {
    v.iter().map(|i| Operand::IdRef(*i)).collect()
}

impl<'m> Rewriter<'m> {
    pub fn new(
        module: &'m mut Module,
        scan: &Scan,
        library: &Library,
        options: &LowerOptions,
    ) -> Result<Self, LowerError> {
        let bound = module.header.as_ref().map_or(scan.bound, |h| h.bound);
        let lib = library.clone().shifted(bound);
        let mut types = Types::default();
        types.add_all(&module.types_global_values);
        types.add_all(&lib.module.types_global_values);
        let mut value_types = HashMap::new();
        for inst in module.all_inst_iter() {
            if let (Some(id), Some(ty)) = (inst.result_id, inst.result_type) {
                value_types.insert(id, ty);
            }
        }
        let of = |op: Op| -> HashSet<Word> {
            module
                .types_global_values
                .iter()
                .filter(|i| i.class.opcode == op)
                .filter_map(|i| i.result_id)
                .collect()
        };
        let rq = of(Op::TypeRayQueryKHR);
        let accel = of(Op::TypeAccelerationStructureKHR);
        let nonuniform = module
            .annotations
            .iter()
            .filter(|a| {
                a.class.opcode == Op::Decorate
                    && matches!(
                        a.operands.get(1),
                        Some(Operand::Decoration(Decoration::NonUniform))
                    )
            })
            .filter_map(|a| match a.operands.first() {
                Some(Operand::IdRef(id)) => Some(*id),
                _ => None,
            })
            .collect();
        // The step cap's id must be free in the shader.
        for a in &module.annotations {
            if let [_, Operand::Decoration(Decoration::SpecId), Operand::LiteralBit32(v)] =
                a.operands.as_slice()
            {
                if *v == options.steps_constant_id {
                    return Err(LowerError::SpecIdTaken(*v));
                }
            }
        }
        let handles = queries::number(module, &types, &rq)?;
        let mut r = Rewriter {
            module,
            types,
            value_types,
            next_id: lib.bound(),
            lib,
            rq,
            accel,
            nonuniform,
            uint: 0,
            u64: 0,
            uvec2: 0,
            uvec4: 0,
            image: 0,
            zero: 0,
            invalid: 0,
            front: Vec::new(),
            back: Vec::new(),
            handles,
            version: scan.version,
            stats: Stats {
                query_states: 0,
                instructions: 0,
                structures: 0,
                used_functions: BTreeSet::new(),
            },
        };
        r.declare_front();
        Ok(r)
    }

    fn fresh(&mut self) -> Word {
        let id = self.next_id;
        self.next_id += 1;
        id
    }

    /// The types and constants every rewrite may use, before the shader's own (the
    /// duplicates among them go when the modules are merged).
    fn declare_front(&mut self) {
        let lit = Operand::LiteralBit32;
        self.uint = self.fresh();
        self.u64 = self.fresh();
        self.uvec2 = self.fresh();
        self.uvec4 = self.fresh();
        self.image = self.fresh();
        self.zero = self.fresh();
        self.invalid = self.fresh();
        let front = vec![
            inst(Op::TypeInt, None, Some(self.uint), vec![lit(32), lit(0)]),
            inst(Op::TypeInt, None, Some(self.u64), vec![lit(64), lit(0)]),
            inst(
                Op::TypeVector,
                None,
                Some(self.uvec2),
                vec![Operand::IdRef(self.uint), lit(2)],
            ),
            inst(
                Op::TypeVector,
                None,
                Some(self.uvec4),
                vec![Operand::IdRef(self.uint), lit(4)],
            ),
            // A uniform texel buffer of 32-bit unsigned texels.
            inst(
                Op::TypeImage,
                None,
                Some(self.image),
                vec![
                    Operand::IdRef(self.uint),
                    Operand::Dim(Dim::DimBuffer),
                    lit(0),
                    lit(0),
                    lit(0),
                    lit(1),
                    Operand::ImageFormat(ImageFormat::Unknown),
                ],
            ),
            inst(Op::Constant, Some(self.uint), Some(self.zero), vec![lit(0)]),
            inst(
                Op::Constant,
                Some(self.uint),
                Some(self.invalid),
                vec![lit(u32::MAX)],
            ),
        ];
        self.types.add_all(&front);
        // A query's value is a handle, a structure's an address.
        let (uint, u64) = (front[0].clone(), front[1].clone());
        for q in self.rq.clone() {
            let mut t = uint.clone();
            t.result_id = Some(q);
            self.types.insert(&t);
        }
        for a in self.accel.clone() {
            let mut t = u64.clone();
            t.result_id = Some(a);
            self.types.insert(&t);
        }
        self.front = front;
    }

    /// Rewrites the shader; returns what it did and the library, its ids shifted past the
    /// shader's, to link.
    pub fn run(mut self) -> Result<(Stats, Library), LowerError> {
        self.rewrite_functions()?;
        self.rewrite_globals();
        self.fix_capabilities();
        self.stats.query_states = self.handles.count;
        if let Some(h) = self.module.header.as_mut() {
            h.bound = self.next_id;
        }
        let mut lib = self.lib;
        if let Some(h) = lib.module.header.as_mut() {
            h.bound = self.next_id;
        }
        Ok((self.stats, lib))
    }

    /// The initializer of a query variable of pointer type `ptr` whose handles start at
    /// `first`: a constant, or a constant array of them. New constants go to `out`.
    fn initializer(&mut self, ptr: Word, first: u32, out: &mut Vec<Instruction>) -> Word {
        let pointee = self.types.pointer(ptr).map_or(0, |(_, p)| p);
        self.constant_of(pointee, first, out)
    }

    fn constant_of(&mut self, ty: Word, first: u32, out: &mut Vec<Instruction>) -> Word {
        // (the nesting was bounded when the variable's handles were counted)
        if self.rq.contains(&ty) {
            let id = self.fresh();
            out.push(inst(
                Op::Constant,
                Some(self.uint),
                Some(id),
                vec![Operand::LiteralBit32(first)],
            ));
            return id;
        }
        let element = self.types.element(ty).unwrap_or(0);
        let len = self
            .types
            .get(ty)
            .and_then(|t| match t.operands.get(1) {
                Some(Operand::IdRef(l)) => self.types.constant_u32(*l),
                _ => None,
            })
            .unwrap_or(0);
        let per = queries::queries_in(&self.types, &self.rq, element).unwrap_or(1);
        let parts: Vec<Word> = (0..len)
            .map(|i| self.constant_of(element, first + i * per, out))
            .collect();
        let id = self.fresh();
        out.push(inst(Op::ConstantComposite, Some(ty), Some(id), ids(&parts)));
        id
    }

    fn rewrite_functions(&mut self) -> Result<(), LowerError> {
        let mut functions = std::mem::take(&mut self.module.functions);
        let result = (|| {
            for f in functions.iter_mut() {
                let mut temps = Temps::default();
                for b in 0..f.blocks.len() {
                    let old = std::mem::take(&mut f.blocks[b].instructions);
                    let mut out = Vec::with_capacity(old.len());
                    for i in old {
                        self.rewrite(i, &mut out, &mut temps)?;
                    }
                    f.blocks[b].instructions = out;
                }
                if let Some(first) = f.blocks.first_mut() {
                    let mut vars = temps.vars;
                    vars.append(&mut first.instructions);
                    first.instructions = vars;
                }
            }
            Ok(())
        })();
        self.module.functions = functions;
        result
    }

    /// The library function `name`, marked used.
    fn function(&mut self, name: &str) -> Result<(Word, Word, Vec<Word>), LowerError> {
        let id = *self
            .lib
            .functions
            .get(name)
            .unwrap_or_else(|| panic!("vkrt's SPIR-V library lacks vkrt_spv_{name}"));
        let (ret, params) = self
            .lib
            .signature(id)
            .expect("a library function's signature");
        self.stats.used_functions.insert(id);
        Ok((id, ret, params))
    }

    /// Calls library function `name` with `args`; its result becomes the shader's
    /// `result` (type, id), bitcast where only the signedness differs.
    fn call(
        &mut self,
        name: &str,
        args: &[Word],
        result: Option<(Word, Word)>,
        what: &Instruction,
        out: &mut Vec<Instruction>,
        temps: &mut Temps,
    ) -> Result<(), LowerError> {
        let (fid, ret, params) = self.function(name)?;
        let mut slots: HashMap<Word, usize> = HashMap::new();
        let mut pointers = Vec::new();
        for (arg, param) in args.iter().zip(&params) {
            let pointee = self.types.pointer(*param).map_or(0, |(_, p)| p);
            let value = self.adapt(*arg, pointee, what, out)?;
            let k = slots.entry(*param).or_insert(0);
            let var = temps.get(*param, *k, || {
                let id = self.next_id;
                self.next_id += 1;
                id
            });
            *k += 1;
            out.push(inst(Op::Store, None, None, ids(&[var, value])));
            pointers.push(var);
        }
        let mut operands = vec![Operand::IdRef(fid)];
        operands.extend(ids(&pointers));
        match result {
            None => {
                let id = self.fresh();
                out.push(inst(Op::FunctionCall, Some(ret), Some(id), operands));
            }
            Some((ty, id)) => {
                let (have, want) = (self.types.shape(ret), self.types.shape(ty));
                if let (true, Shape::Array(_, n)) = (have == want, &want) {
                    // Arrays are declared once per module (the library's and the shader's
                    // stay apart): the shader's is built from the library's elements.
                    let tmp = self.fresh();
                    out.push(inst(Op::FunctionCall, Some(ret), Some(tmp), operands));
                    let element = self.types.element(ret).unwrap_or(0);
                    let parts: Vec<Word> = (0..*n)
                        .map(|k| {
                            let part = self.fresh();
                            out.push(inst(
                                Op::CompositeExtract,
                                Some(element),
                                Some(part),
                                vec![Operand::IdRef(tmp), Operand::LiteralBit32(k)],
                            ));
                            part
                        })
                        .collect();
                    out.push(inst(
                        Op::CompositeConstruct,
                        Some(ty),
                        Some(id),
                        ids(&parts),
                    ));
                } else if have == want {
                    out.push(inst(Op::FunctionCall, Some(ty), Some(id), operands));
                } else if have.bitcasts_to(&want) {
                    let tmp = self.fresh();
                    out.push(inst(Op::FunctionCall, Some(ret), Some(tmp), operands));
                    out.push(inst(Op::Bitcast, Some(ty), Some(id), ids(&[tmp])));
                } else {
                    return Err(self.unsupported(what, format!("its result type {want:?}")));
                }
            }
        }
        Ok(())
    }

    /// `value` as a value of type `want`: itself, or bitcast between signed and unsigned.
    fn adapt(
        &mut self,
        value: Word,
        want: Word,
        what: &Instruction,
        out: &mut Vec<Instruction>,
    ) -> Result<Word, LowerError> {
        let ty = self.value_types.get(&value).copied().unwrap_or(0);
        let (have, wanted) = (self.types.shape(ty), self.types.shape(want));
        if have == wanted {
            Ok(value)
        } else if have.bitcasts_to(&wanted) {
            let id = self.fresh();
            out.push(inst(Op::Bitcast, Some(want), Some(id), ids(&[value])));
            Ok(id)
        } else {
            Err(self.unsupported(
                what,
                format!("an operand of type {have:?} where {wanted:?} is taken"),
            ))
        }
    }

    fn unsupported(&self, what: &Instruction, reason: String) -> LowerError {
        LowerError::Unsupported {
            instruction: format!("Op{}", what.class.opname),
            offset: 0,
            reason,
        }
    }

    fn id_operand(i: &Instruction, n: usize) -> Word {
        match i.operands.get(n) {
            Some(Operand::IdRef(id)) => *id,
            _ => 0,
        }
    }

    fn rewrite(
        &mut self,
        i: Instruction,
        out: &mut Vec<Instruction>,
        temps: &mut Temps,
    ) -> Result<(), LowerError> {
        let op = i.class.opcode;
        let arg = |n: usize| Self::id_operand(&i, n);
        // A query operand: the handle its variable holds.
        let handle = |s: &mut Self, out: &mut Vec<Instruction>| {
            let h = s.fresh();
            out.push(inst(Op::Load, Some(s.uint), Some(h), ids(&[arg(0)])));
            s.value_types.insert(h, s.uint);
            h
        };
        let result = i.result_type.zip(i.result_id);
        let getter = |op: Op| -> Option<(&'static str, bool)> {
            // (library function, takes the Intersection operand)
            Some(match op {
                Op::RayQueryGetIntersectionTypeKHR => ("type", true),
                Op::RayQueryGetIntersectionTKHR => ("t", true),
                Op::RayQueryGetIntersectionInstanceCustomIndexKHR => {
                    ("instance_custom_index", true)
                }
                Op::RayQueryGetIntersectionInstanceIdKHR => ("instance_id", true),
                Op::RayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetKHR => {
                    ("sbt_record_offset", true)
                }
                Op::RayQueryGetIntersectionGeometryIndexKHR => ("geometry_index", true),
                Op::RayQueryGetIntersectionPrimitiveIndexKHR => ("primitive_index", true),
                Op::RayQueryGetIntersectionBarycentricsKHR => ("barycentrics", true),
                Op::RayQueryGetIntersectionFrontFaceKHR => ("front_face", true),
                Op::RayQueryGetIntersectionObjectRayDirectionKHR => ("object_ray_direction", true),
                Op::RayQueryGetIntersectionObjectRayOriginKHR => ("object_ray_origin", true),
                Op::RayQueryGetIntersectionObjectToWorldKHR => ("object_to_world", true),
                Op::RayQueryGetIntersectionWorldToObjectKHR => ("world_to_object", true),
                Op::RayQueryGetIntersectionCandidateAABBOpaqueKHR => {
                    ("candidate_aabb_opaque", false)
                }
                Op::RayQueryGetRayTMinKHR => ("ray_tmin", false),
                Op::RayQueryGetRayFlagsKHR => ("ray_flags", false),
                Op::RayQueryGetWorldRayOriginKHR => ("world_ray_origin", false),
                Op::RayQueryGetWorldRayDirectionKHR => ("world_ray_direction", false),
                Op::RayQueryGetIntersectionTriangleVertexPositionsKHR => {
                    ("triangle_vertex_positions", true)
                }
                Op::RayQueryProceedKHR => ("proceed", false),
                _ => return None,
            })
        };
        match op {
            Op::RayQueryInitializeKHR => {
                self.stats.instructions += 1;
                let h = handle(self, out);
                let args = [h, arg(1), arg(2), arg(3), arg(4), arg(5), arg(6), arg(7)];
                self.call("initialize", &args, None, &i, out, temps)
            }
            Op::RayQueryTerminateKHR | Op::RayQueryConfirmIntersectionKHR => {
                self.stats.instructions += 1;
                let h = handle(self, out);
                let name = if op == Op::RayQueryTerminateKHR {
                    "terminate"
                } else {
                    "confirm"
                };
                self.call(name, &[h], None, &i, out, temps)
            }
            Op::RayQueryGenerateIntersectionKHR => {
                self.stats.instructions += 1;
                let h = handle(self, out);
                self.call("generate", &[h, arg(1)], None, &i, out, temps)
            }
            _ if getter(op).is_some() => {
                self.stats.instructions += 1;
                let (name, committed) = getter(op).unwrap_or(("", false));
                let h = handle(self, out);
                let args: Vec<Word> = if committed { vec![h, arg(1)] } else { vec![h] };
                self.call(name, &args, result, &i, out, temps)
            }
            Op::ConvertUToAccelerationStructureKHR => {
                self.stats.instructions += 1;
                let v = arg(0);
                let ty = self.value_types.get(&v).copied().unwrap_or(0);
                let (_, id) = result.unwrap_or((0, 0));
                let copy = if self.types.shape(ty) == self.types.shape(self.u64) {
                    Op::CopyObject
                } else {
                    Op::Bitcast
                };
                out.push(inst(copy, Some(self.u64), Some(id), ids(&[v])));
                Ok(())
            }
            Op::Load
                if result.is_some_and(|(ty, _)| self.accel.contains(&ty))
                    && self.is_descriptor(arg(0)) =>
            {
                // The texel buffer's first texel: the handle's address, low word first.
                self.stats.instructions += 1;
                let (_, id) = result.unwrap_or((0, 0));
                let (img, texel, xy) = (self.fresh(), self.fresh(), self.fresh());
                let mut load = i.clone();
                load.result_type = Some(self.image);
                load.result_id = Some(img);
                out.push(load);
                out.push(inst(
                    Op::ImageFetch,
                    Some(self.uvec4),
                    Some(texel),
                    ids(&[img, self.zero]),
                ));
                out.push(inst(
                    Op::VectorShuffle,
                    Some(self.uvec2),
                    Some(xy),
                    vec![
                        Operand::IdRef(texel),
                        Operand::IdRef(texel),
                        Operand::LiteralBit32(0),
                        Operand::LiteralBit32(1),
                    ],
                ));
                out.push(inst(Op::Bitcast, Some(self.u64), Some(id), ids(&[xy])));
                if self.nonuniform.contains(&id) {
                    for t in [img, texel] {
                        self.module.annotations.push(inst(
                            Op::Decorate,
                            None,
                            None,
                            vec![
                                Operand::IdRef(t),
                                Operand::Decoration(Decoration::NonUniform),
                            ],
                        ));
                    }
                }
                Ok(())
            }
            Op::Variable if self.handles.of.contains_key(&i.result_id.unwrap_or(0)) => {
                let (first, _) = self.handles.of[&i.result_id.unwrap_or(0)];
                let mut back = std::mem::take(&mut self.back);
                let init = self.initializer(i.result_type.unwrap_or(0), first, &mut back);
                self.back = back;
                let mut v = i;
                v.operands.truncate(1);
                v.operands.push(Operand::IdRef(init));
                out.push(v);
                Ok(())
            }
            Op::Undef if result.is_some_and(|(ty, _)| self.rq.contains(&ty)) => {
                let (_, id) = result.unwrap_or((0, 0));
                out.push(inst(
                    Op::CopyObject,
                    Some(self.uint),
                    Some(id),
                    ids(&[self.invalid]),
                ));
                Ok(())
            }
            _ => {
                out.push(i);
                Ok(())
            }
        }
    }

    /// Whether `pointer` points at a bound structure (UniformConstant storage).
    fn is_descriptor(&self, pointer: Word) -> bool {
        let ty = self.value_types.get(&pointer).copied().unwrap_or(0);
        matches!(
            self.types.pointer(ty),
            Some((StorageClass::UniformConstant, _))
        )
    }

    /// The type section: queries become handles, structures addresses (texel buffers
    /// where bound), and Private query variables get their handles.
    fn rewrite_globals(&mut self) {
        let old = std::mem::take(&mut self.module.types_global_values);
        let mut out = std::mem::take(&mut self.front);
        let mut subst: HashMap<Word, Word> = HashMap::new();
        for q in &self.rq {
            subst.insert(*q, self.uint);
        }
        for a in &self.accel {
            subst.insert(*a, self.u64);
        }
        let mut structures = 0;
        for mut i in old {
            let id = i.result_id.unwrap_or(0);
            match i.class.opcode {
                Op::TypeRayQueryKHR | Op::TypeAccelerationStructureKHR => continue,
                Op::TypeArray | Op::TypeRuntimeArray => {
                    if let Some(Operand::IdRef(e)) = i.operands.first_mut() {
                        if self.accel.contains(e) {
                            *e = self.image;
                        }
                    }
                }
                Op::TypePointer => {
                    if let [Operand::StorageClass(StorageClass::UniformConstant), Operand::IdRef(p)] =
                        i.operands.as_mut_slice()
                    {
                        if self.accel.contains(p) {
                            *p = self.image;
                        }
                    }
                }
                Op::Variable => {
                    if self.is_structure_variable(&i) {
                        structures += 1;
                    }
                    if let Some(&(first, _)) = self.handles.of.get(&id) {
                        let init = self.initializer(i.result_type.unwrap_or(0), first, &mut out);
                        i.operands.truncate(1);
                        i.operands.push(Operand::IdRef(init));
                    }
                }
                Op::Undef if i.result_type.is_some_and(|t| self.rq.contains(&t)) => {
                    i = inst(
                        Op::Constant,
                        Some(self.uint),
                        Some(id),
                        vec![Operand::LiteralBit32(u32::MAX)],
                    );
                }
                _ => {}
            }
            out.push(i);
        }
        out.append(&mut self.back);
        self.module.types_global_values = out;
        self.stats.structures = structures;
        let removed: HashSet<Word> = self.rq.union(&self.accel).copied().collect();
        self.module
            .debug_names
            .retain(|n| !removed.iter().any(|r| decorates(n, *r)));
        self.module
            .annotations
            .retain(|a| !removed.iter().any(|r| decorates(a, *r)));
        for i in self.module.all_inst_iter_mut() {
            super::library::shift_ids(i, &|id: &mut Word| {
                if let Some(s) = subst.get(id) {
                    *id = *s;
                }
            });
        }
    }

    fn is_structure_variable(&self, v: &Instruction) -> bool {
        let Some((StorageClass::UniformConstant, mut p)) =
            v.result_type.and_then(|t| self.types.pointer(t))
        else {
            return false;
        };
        for _ in 0..super::queries::MAX_NESTING {
            match self.types.element(p) {
                Some(e) => p = e,
                None => break,
            }
        }
        self.accel.contains(&p)
    }

    fn fix_capabilities(&mut self) {
        let cap_of = |i: &Instruction| match i.operands.first() {
            Some(Operand::Capability(c)) => Some(*c),
            _ => None,
        };
        let gone = [
            Capability::RayQueryKHR,
            Capability::RayQueryProvisionalKHR,
            Capability::RayTraversalPrimitiveCullingKHR,
            Capability::RayQueryPositionFetchKHR,
        ];
        self.module
            .capabilities
            .retain(|i| !cap_of(i).is_some_and(|c| gone.contains(&c)));
        let mut wanted = vec![
            Capability::Int64,
            Capability::PhysicalStorageBufferAddresses,
        ];
        if self.stats.structures > 0 {
            wanted.push(Capability::SampledBuffer);
        }
        for c in wanted {
            if !self
                .module
                .capabilities
                .iter()
                .any(|i| cap_of(i) == Some(c))
            {
                self.module.capabilities.push(inst(
                    Op::Capability,
                    None,
                    None,
                    vec![Operand::Capability(c)],
                ));
            }
        }
        self.module.extensions.retain(|e| {
            !matches!(e.operands.first(), Some(Operand::LiteralString(s))
                if s == "SPV_KHR_ray_query"
                    || s == "SPV_KHR_ray_tracing"
                    || s == "SPV_KHR_ray_tracing_position_fetch")
        });
        if self.version.1 < 5 {
            add_extension(self.module, "SPV_KHR_physical_storage_buffer");
        }
        if let Some(mm) = self.module.memory_model.as_mut() {
            if let Some(Operand::AddressingModel(a)) = mm.operands.first_mut() {
                *a = AddressingModel::PhysicalStorageBuffer64;
            }
        }
    }
}

pub(crate) fn add_extension(module: &mut Module, name: &str) {
    let has = module
        .extensions
        .iter()
        .any(|e| matches!(e.operands.first(), Some(Operand::LiteralString(s)) if s == name));
    if !has {
        module.extensions.push(inst(
            Op::Extension,
            None,
            None,
            vec![Operand::LiteralString(name.into())],
        ));
    }
}

/// A function's variables for the library's parameters (glslang passes every parameter
/// by pointer): one per pointer type and position within a call, reused by every call.
#[derive(Default)]
struct Temps {
    by: HashMap<(Word, usize), Word>,
    vars: Vec<Instruction>,
}

impl Temps {
    fn get(&mut self, ptr: Word, k: usize, mut fresh: impl FnMut() -> Word) -> Word {
        if let Some(v) = self.by.get(&(ptr, k)) {
            return *v;
        }
        let id = fresh();
        self.vars.push(inst(
            Op::Variable,
            Some(ptr),
            Some(id),
            vec![Operand::StorageClass(StorageClass::Function)],
        ));
        self.by.insert((ptr, k), id);
        id
    }
}
