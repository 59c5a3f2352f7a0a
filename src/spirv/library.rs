//! The walk as a SPIR-V library: `glsl/spirv/ray_query_library.comp`, compiled unoptimised
//! with the kernels, parsed once per process.

use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{Decoration, Op, StorageClass, Word};
use std::collections::HashMap;
use std::sync::OnceLock;

/// The specialization constant ids the library's GLSL gives its state count, its step cap
/// and the switch that keeps its functions (`glsl/spirv/ray_query_library.comp`).
pub(crate) const COUNT_SPEC_ID: u32 = 1899;
pub(crate) const STEPS_SPEC_ID: u32 = crate::accel::shader_library::STEPS_CONSTANT_ID;
const KEEP_SPEC_ID: u32 = 1898;
/// The library's switch of the loop-budget walk (`LowerOptions::loop_budget`), which the
/// pass makes a constant.
pub(crate) const LOOP_BUDGET_SPEC_ID: u32 = 1897;

/// The library's SPIR-V version, the oldest input the pass takes.
const LIBRARY_VERSION: (u8, u8) = (1, 3);

/// The parsed library, its ids shifted by `offset` once linked.
#[derive(Clone)]
pub(crate) struct Library {
    pub module: Module,
    /// `vkrt_spv_*` functions by name (without `vkrt_spv_` and the parameter list).
    pub functions: HashMap<String, Word>,
    /// The id of its `main`, which only keeps the functions alive.
    pub main: Word,
    /// The specialization constants of the state count and of the step cap.
    pub count: Word,
    pub steps: Word,
    /// The specialization constant of the loop-budget walk.
    pub loop_budget: Word,
}

/// The library, parsed from the checked-in SPIR-V (a failure here is a build error of
/// vkrt's, which the tests catch).
pub(crate) fn load() -> Library {
    static LIBRARY: OnceLock<Library> = OnceLock::new();
    LIBRARY
        .get_or_init(|| parse(crate::gpu::kernels::SPIRV_RAY_QUERY_LIBRARY.spirv))
        .clone()
}

fn parse(words: &[u32]) -> Library {
    let mut module = rspirv::dr::load_words(words).expect("vkrt's SPIR-V library parses");
    let header = module.header.as_ref().expect("the library has a header");
    assert_eq!(
        header.version(),
        LIBRARY_VERSION,
        "the library's SPIR-V version"
    );
    let mut functions = HashMap::new();
    let mut main = 0;
    for inst in &module.debug_names {
        if let (Op::Name, Some(Operand::IdRef(id)), Some(Operand::LiteralString(name))) = (
            inst.class.opcode,
            inst.operands.first(),
            inst.operands.get(1),
        ) {
            let base = name.split('(').next().unwrap_or(name);
            if let Some(short) = base.strip_prefix("vkrt_spv_") {
                functions.insert(short.to_string(), *id);
            } else if base == "main" && main == 0 {
                main = *id;
            }
        }
    }
    assert!(main != 0, "the library names its main");
    let spec = |wanted: u32| {
        module
            .annotations
            .iter()
            .find_map(|a| match (a.class.opcode, a.operands.as_slice()) {
                (
                    Op::Decorate,
                    [Operand::IdRef(id), Operand::Decoration(Decoration::SpecId), Operand::LiteralBit32(v)],
                ) if *v == wanted => Some(*id),
                _ => None,
            })
            .expect("the library's specialization constants")
    };
    let (count, steps, keep) = (spec(COUNT_SPEC_ID), spec(STEPS_SPEC_ID), spec(KEEP_SPEC_ID));
    let loop_budget = spec(LOOP_BUDGET_SPEC_ID);
    assert_eq!(
        version(&module, functions["version"]),
        Some(crate_version()),
        "the SPIR-V library's VKRT_VERSION is its crate's"
    );
    hoist_global_initializers(&mut module, main);
    // The switch that keeps the functions is never on; its SpecId goes, so that it cannot
    // meet the shader's own.
    module.annotations.retain(|a| !decorates(a, keep));
    Library {
        module,
        functions,
        main,
        count,
        steps,
        loop_budget,
    }
}

/// The crate's version as the GLSL library writes it (`VKRT_VERSION`): major * 10000 +
/// minor * 100 + patch.
pub(crate) fn crate_version() -> u32 {
    let part = |s: &str| s.parse::<u32>().unwrap_or(0);
    part(env!("CARGO_PKG_VERSION_MAJOR")) * 10_000
        + part(env!("CARGO_PKG_VERSION_MINOR")) * 100
        + part(env!("CARGO_PKG_VERSION_PATCH"))
}

/// The constant function `f` returns (the library's `vkrt_spv_version`).
fn version(module: &Module, f: Word) -> Option<u32> {
    let func = module.functions.iter().find(|x| x.def_id() == Some(f))?;
    let ret = func
        .blocks
        .iter()
        .flat_map(|b| &b.instructions)
        .find(|i| i.class.opcode == Op::ReturnValue)?;
    let Some(Operand::IdRef(value)) = ret.operands.first() else {
        return None;
    };
    module.types_global_values.iter().find_map(|i| {
        match (
            i.result_id == Some(*value),
            i.class.opcode,
            i.operands.first(),
        ) {
            (true, Op::Constant, Some(Operand::LiteralBit32(v))) => Some(*v),
            _ => None,
        }
    })
}

/// glslang sets a global's initial value at the start of `main` (`bool x = false;`);
/// without `main` those become the variables' initializers.
fn hoist_global_initializers(module: &mut Module, main: Word) {
    // Private variables without an initializer.
    let private: Vec<Word> = private_variables(&module.types_global_values)
        .filter(|i| i.operands.len() == 1)
        .filter_map(|i| i.result_id)
        .collect();
    let constants: Vec<Word> = module
        .types_global_values
        .iter()
        .filter(|i| {
            matches!(
                i.class.opcode,
                Op::Constant
                    | Op::ConstantTrue
                    | Op::ConstantFalse
                    | Op::ConstantComposite
                    | Op::ConstantNull
            )
        })
        .filter_map(|i| i.result_id)
        .collect();
    let Some(f) = module.functions.iter().find(|f| f.def_id() == Some(main)) else {
        return;
    };
    let mut initial = HashMap::new();
    for inst in f
        .blocks
        .first()
        .map(|b| b.instructions.as_slice())
        .unwrap_or(&[])
    {
        match (inst.class.opcode, inst.operands.as_slice()) {
            (Op::Variable, _) => continue,
            (Op::Store, [Operand::IdRef(p), Operand::IdRef(v), ..])
                if private.contains(p) && constants.contains(v) =>
            {
                initial.insert(*p, *v);
            }
            _ => break,
        }
    }
    // The variables move after every constant, their initializers among them.
    let (mut moved, kept): (Vec<_>, Vec<_>) = std::mem::take(&mut module.types_global_values)
        .into_iter()
        .partition(|i| i.result_id.is_some_and(|id| initial.contains_key(&id)));
    for inst in moved.iter_mut() {
        if let Some(v) = inst.result_id.and_then(|id| initial.get(&id)) {
            inst.operands.push(Operand::IdRef(*v));
        }
    }
    module.types_global_values = kept;
    module.types_global_values.append(&mut moved);
}

/// The `Private` variables among a module's globals.
pub(crate) fn private_variables(globals: &[Instruction]) -> impl Iterator<Item = &Instruction> {
    globals.iter().filter(|i| {
        i.class.opcode == Op::Variable
            && matches!(
                i.operands.first(),
                Some(Operand::StorageClass(StorageClass::Private))
            )
    })
}

/// Whether annotation `a` decorates `id`.
pub(crate) fn decorates(a: &Instruction, id: Word) -> bool {
    matches!(a.operands.first(), Some(Operand::IdRef(t)) if *t == id)
}

impl Library {
    /// Shifts every id by `by`, so that the library's ids follow the shader's.
    pub fn shifted(mut self, by: Word) -> Library {
        let shift = |id: &mut Word| *id += by;
        for inst in self.module.all_inst_iter_mut() {
            shift_ids(inst, &shift);
        }
        for id in self.functions.values_mut() {
            *id += by;
        }
        self.main += by;
        self.count += by;
        self.steps += by;
        self.loop_budget += by;
        if let Some(h) = self.module.header.as_mut() {
            h.bound += by;
        }
        self
    }

    pub fn bound(&self) -> Word {
        self.module.header.as_ref().map_or(0, |h| h.bound)
    }

    /// A function's id, its return type and its parameters' pointer types.
    pub fn signature(&self, id: Word) -> Option<(Word, Vec<Word>)> {
        let f = self
            .module
            .functions
            .iter()
            .find(|f| f.def_id() == Some(id))?;
        let ret = f.def.as_ref()?.result_type?;
        Some((
            ret,
            f.parameters.iter().filter_map(|p| p.result_type).collect(),
        ))
    }
}

/// Applies `f` to every id `inst` defines or names.
pub(crate) fn shift_ids(inst: &mut Instruction, f: &impl Fn(&mut Word)) {
    if let Some(id) = inst.result_id.as_mut() {
        f(id);
    }
    if let Some(id) = inst.result_type.as_mut() {
        f(id);
    }
    for o in inst.operands.iter_mut() {
        if let Operand::IdRef(id) | Operand::IdScope(id) | Operand::IdMemorySemantics(id) = o {
            f(id);
        }
    }
}
