//! Links the library's functions into the rewritten shader: the functions it calls and
//! what they call, the library's globals, capabilities and decorations; then every type
//! and constant declared twice is declared once (SPIR-V allows no duplicate scalar,
//! vector, matrix, image, pointer or function types).

use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{Decoration, Op, Word};
use std::collections::{BTreeSet, HashMap, HashSet};

use super::library::{private_variables, shift_ids, Library};
use super::rewrite::{add_extension, Stats};
use super::words::Scan;
use super::LowerOptions;

/// Links `lib` (its ids already past the shader's) into `module`; returns the number of
/// functions linked.
pub(crate) fn link(
    module: &mut Module,
    lib: Library,
    stats: &Stats,
    options: &LowerOptions,
    scan: &Scan,
) -> usize {
    let Library {
        module: mut lm,
        main,
        count,
        steps,
        loop_budget,
        ..
    } = lib;
    let needed = closure(&lm, &stats.used_functions);
    let mut subst: HashMap<Word, Word> = HashMap::new();

    for c in lm.capabilities.drain(..) {
        if !module.capabilities.iter().any(|m| m.operands == c.operands) {
            module.capabilities.push(c);
        }
    }
    for e in lm.extensions.drain(..) {
        if let Some(Operand::LiteralString(name)) = e.operands.first() {
            add_extension(module, name);
        }
    }
    for imp in lm.ext_inst_imports.drain(..) {
        let same = module
            .ext_inst_imports
            .iter()
            .find(|m| m.operands == imp.operands)
            .and_then(|m| m.result_id);
        match (same, imp.result_id) {
            (Some(app), Some(ours)) => {
                subst.insert(ours, app);
            }
            _ => module.ext_inst_imports.push(imp),
        }
    }

    // The state count becomes a constant: the entry points' static count; so does the
    // choice of the loop-budget walk.
    for inst in lm.types_global_values.iter_mut() {
        if inst.result_id == Some(count) {
            *inst = Instruction::new(
                Op::Constant,
                inst.result_type,
                Some(count),
                vec![Operand::LiteralBit32(stats.query_states)],
            );
        } else if inst.result_id == Some(loop_budget) {
            let op = if options.loop_budget {
                Op::ConstantTrue
            } else {
                Op::ConstantFalse
            };
            *inst = Instruction::new(op, inst.result_type, Some(loop_budget), vec![]);
        }
    }
    let library_privates: Vec<Word> = private_variables(&lm.types_global_values)
        .filter_map(|i| i.result_id)
        .collect();
    module
        .types_global_values
        .append(&mut lm.types_global_values);
    let mut linked = 0;
    for mut f in lm.functions.drain(..) {
        let id = f.def_id().unwrap_or(0);
        if id == main || !needed.contains(&id) {
            continue;
        }
        for b in f.blocks.iter_mut() {
            b.instructions
                .retain(|i| !matches!(i.class.opcode, Op::Line | Op::NoLine));
        }
        module.functions.push(f);
        linked += 1;
    }

    // The library's decorations of what was linked: not its main's, not its compute
    // built-ins (gl_WorkGroupSize), not the state count's or the loop-budget walk's SpecId;
    // the step cap's SpecId is the caller's.
    let defined: HashSet<Word> = module.all_inst_iter().filter_map(|i| i.result_id).collect();
    for mut a in lm.annotations.drain(..) {
        let target = match a.operands.first() {
            Some(Operand::IdRef(t)) => *t,
            _ => continue,
        };
        if !defined.contains(&target) || target == count || target == loop_budget {
            continue;
        }
        match a.operands.get(1) {
            Some(Operand::Decoration(Decoration::BuiltIn)) => continue,
            Some(Operand::Decoration(Decoration::SpecId)) if target == steps => {
                a.operands[2] = Operand::LiteralBit32(options.steps_constant_id);
            }
            Some(Operand::Decoration(Decoration::SpecId)) => continue,
            _ => {}
        }
        module.annotations.push(a);
    }

    dedup(module, &mut subst);

    // SPIR-V 1.4 and later list every global an entry point uses in its interface.
    if scan.version.1 >= 4 {
        let privates: Vec<Word> = library_privates
            .iter()
            .map(|p| subst.get(p).copied().unwrap_or(*p))
            .collect();
        for ep in module.entry_points.iter_mut() {
            let listed: HashSet<Word> = ep
                .operands
                .iter()
                .skip(3)
                .filter_map(|o| match o {
                    Operand::IdRef(id) => Some(*id),
                    _ => None,
                })
                .collect();
            for p in &privates {
                if !listed.contains(p) {
                    ep.operands.push(Operand::IdRef(*p));
                }
            }
        }
    }
    let bound = lm.header.as_ref().map_or(0, |h| h.bound);
    if let Some(h) = module.header.as_mut() {
        h.bound = h.bound.max(bound);
    }
    linked
}

/// The library functions `used` and every function they call.
fn closure(lm: &Module, used: &BTreeSet<Word>) -> HashSet<Word> {
    let calls: HashMap<Word, Vec<Word>> = lm
        .functions
        .iter()
        .map(|f| {
            let callees = f
                .blocks
                .iter()
                .flat_map(|b| &b.instructions)
                .filter(|i| i.class.opcode == Op::FunctionCall)
                .filter_map(|i| match i.operands.first() {
                    Some(Operand::IdRef(c)) => Some(*c),
                    _ => None,
                })
                .collect();
            (f.def_id().unwrap_or(0), callees)
        })
        .collect();
    let mut seen: HashSet<Word> = HashSet::new();
    let mut todo: Vec<Word> = used.iter().copied().collect();
    while let Some(f) = todo.pop() {
        if seen.insert(f) {
            todo.extend(calls.get(&f).into_iter().flatten().copied());
        }
    }
    seen
}

/// Declares each undecorated scalar, vector, matrix, image, sampler, pointer and function
/// type, and each plain constant, once; `subst` gains every id that went and its
/// survivor, and every instruction follows it.
fn dedup(module: &mut Module, subst: &mut HashMap<Word, Word>) {
    let decorated: HashSet<Word> = module
        .annotations
        .iter()
        .filter_map(|a| match a.operands.first() {
            Some(Operand::IdRef(t)) => Some(*t),
            _ => None,
        })
        .collect();
    let forward: HashSet<Word> = module
        .types_global_values
        .iter()
        .filter(|i| i.class.opcode == Op::TypeForwardPointer)
        .filter_map(|i| match i.operands.first() {
            Some(Operand::IdRef(p)) => Some(*p),
            _ => None,
        })
        .collect();
    let mut seen: HashMap<String, Word> = HashMap::new();
    let old = std::mem::take(&mut module.types_global_values);
    let mut kept = Vec::with_capacity(old.len());
    for mut i in old {
        follow(&mut i, subst);
        let id = i.result_id.unwrap_or(0);
        let merges = matches!(
            i.class.opcode,
            Op::TypeVoid
                | Op::TypeBool
                | Op::TypeInt
                | Op::TypeFloat
                | Op::TypeVector
                | Op::TypeMatrix
                | Op::TypeImage
                | Op::TypeSampler
                | Op::TypeSampledImage
                | Op::TypePointer
                | Op::TypeFunction
                | Op::Constant
                | Op::ConstantTrue
                | Op::ConstantFalse
                | Op::ConstantComposite
                | Op::ConstantNull
        ) && !decorated.contains(&id)
            && !forward.contains(&id);
        if merges {
            let key = format!("{:?} {:?} {:?}", i.class.opcode, i.result_type, i.operands);
            if let Some(&first) = seen.get(&key) {
                subst.insert(id, first);
                continue;
            }
            seen.insert(key, id);
        }
        kept.push(i);
    }
    module.types_global_values = kept;
    for i in module.all_inst_iter_mut() {
        follow(i, subst);
    }
    module.debug_names.retain(
        |n| !matches!(n.operands.first(), Some(Operand::IdRef(t)) if subst.contains_key(t)),
    );
}

fn follow(i: &mut Instruction, subst: &HashMap<Word, Word>) {
    let result = i.result_id;
    shift_ids(i, &|id: &mut Word| {
        if let Some(s) = subst.get(id) {
            *id = *s;
        }
    });
    // A survivor keeps its own id.
    i.result_id = result;
}
