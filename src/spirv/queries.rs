//! Query handles: which query states each query variable names.
//!
//! A query's handle is the index of its state. Private query variables take the first
//! indices; each function's own query variables come after those of every function on any
//! call path to it, so a query live in a caller is never one a callee declares, and two
//! functions never live at once (siblings) share indices. The count is the entry points'
//! largest: the static count, with no recycling at run time.

use rspirv::dr::{Module, Operand};
use rspirv::spirv::{Op, StorageClass, Word};
use std::collections::{HashMap, HashSet};

use super::types::Types;
use super::LowerError;

/// How deep types may nest (arrays of arrays, vectors of ...): deeper is a cycle of ids in
/// a malformed module, refused rather than followed.
pub(crate) const MAX_NESTING: u32 = 64;

/// The first handle and the number of handles of each query variable.
pub(crate) struct Handles {
    pub of: HashMap<Word, (u32, u32)>,
    /// The states an invocation needs (at least 1).
    pub count: u32,
}

/// How many queries a value of type `ty` holds (an array of queries holds one per
/// element); `Err` for a query array whose length is not a plain constant.
pub(crate) fn queries_in(types: &Types, rq: &HashSet<Word>, ty: Word) -> Result<u32, String> {
    queries_within(types, rq, ty, 0)
}

fn queries_within(types: &Types, rq: &HashSet<Word>, ty: Word, depth: u32) -> Result<u32, String> {
    if rq.contains(&ty) {
        return Ok(1);
    }
    if depth > MAX_NESTING {
        return Err(format!(
            "types nested over {MAX_NESTING} deep (a cycle of ids?)"
        ));
    }
    let Some(inst) = types.get(ty) else {
        return Ok(0);
    };
    match inst.class.opcode {
        Op::TypeArray => {
            let (Some(Operand::IdRef(e)), Some(Operand::IdRef(len))) =
                (inst.operands.first(), inst.operands.get(1))
            else {
                return Ok(0);
            };
            let per = queries_within(types, rq, *e, depth + 1)?;
            if per == 0 {
                return Ok(0);
            }
            let n = types
                .constant_u32(*len)
                .ok_or("an array of ray queries sized by a specialization constant")?;
            per.checked_mul(n)
                .ok_or_else(|| "an array of over 2^32 ray queries".to_string())
        }
        Op::TypeRuntimeArray
            if queries_in(
                types,
                rq,
                match inst.operands.first() {
                    Some(Operand::IdRef(e)) => *e,
                    _ => 0,
                },
            )? > 0 =>
        {
            Err("a runtime array of ray queries".into())
        }
        _ => Ok(0),
    }
}

/// Numbers the module's query variables.
pub(crate) fn number(
    module: &Module,
    types: &Types,
    rq: &HashSet<Word>,
) -> Result<Handles, LowerError> {
    let unsupported = |what: String| LowerError::Unsupported {
        instruction: "OpVariable".into(),
        offset: 0,
        reason: what,
    };
    let queries_of_var = |ty: Option<Word>| -> Result<u32, LowerError> {
        let Some((_, pointee)) = ty.and_then(|t| types.pointer(t)) else {
            return Ok(0);
        };
        queries_in(types, rq, pointee).map_err(&unsupported)
    };
    let mut of = HashMap::new();
    let mut next = 0u32;
    for inst in &module.types_global_values {
        if inst.class.opcode != Op::Variable {
            continue;
        }
        let n = queries_of_var(inst.result_type)?;
        if n > 0 {
            if !matches!(
                inst.operands.first(),
                Some(Operand::StorageClass(StorageClass::Private))
            ) {
                return Err(unsupported(
                    "ray queries outside Private and Function storage".into(),
                ));
            }
            of.insert(inst.result_id.unwrap_or(0), (next, n));
            next = next.saturating_add(n);
        }
    }
    let globals = next;

    // Each function's own queries, and whom it calls.
    let mut own: HashMap<Word, u32> = HashMap::new();
    let mut calls: HashMap<Word, Vec<Word>> = HashMap::new();
    let mut locals: HashMap<Word, Vec<(Word, u32)>> = HashMap::new();
    for f in &module.functions {
        let id = f.def_id().unwrap_or(0);
        let mut count = 0u32;
        for inst in f.blocks.iter().flat_map(|b| &b.instructions) {
            match inst.class.opcode {
                Op::Variable => {
                    let n = queries_of_var(inst.result_type)?;
                    if n > 0 {
                        locals
                            .entry(id)
                            .or_default()
                            .push((inst.result_id.unwrap_or(0), n));
                        count = count.saturating_add(n);
                    }
                }
                Op::FunctionCall => {
                    if let Some(Operand::IdRef(callee)) = inst.operands.first() {
                        calls.entry(id).or_default().push(*callee);
                    }
                }
                _ => {}
            }
        }
        own.insert(id, count);
    }

    // Bases in topological order (SPIR-V has no recursion; a cycle is refused).
    let mut order = Vec::new();
    let mut state: HashMap<Word, u8> = HashMap::new();
    for f in &module.functions {
        visit(f.def_id().unwrap_or(0), &calls, &mut state, &mut order)?;
    }
    order.reverse();
    let mut base: HashMap<Word, u32> = order.iter().map(|f| (*f, globals)).collect();
    let mut count = globals;
    for f in &order {
        let b = base[f];
        let end = b.saturating_add(own.get(f).copied().unwrap_or(0));
        count = count.max(end);
        for callee in calls.get(f).into_iter().flatten() {
            let e = base.entry(*callee).or_insert(globals);
            *e = (*e).max(end);
        }
    }
    for (f, vars) in &locals {
        let mut next = base.get(f).copied().unwrap_or(globals);
        for (var, n) in vars {
            of.insert(*var, (next, *n));
            next = next.saturating_add(*n);
        }
    }
    if count > 1 << 16 {
        return Err(unsupported(format!(
            "{count} ray queries live at once in an invocation (at most 65,536)"
        )));
    }
    Ok(Handles {
        of,
        count: count.max(1),
    })
}

fn visit(
    f: Word,
    calls: &HashMap<Word, Vec<Word>>,
    state: &mut HashMap<Word, u8>,
    order: &mut Vec<Word>,
) -> Result<(), LowerError> {
    // Iterative depth-first search (a deep call graph must not overflow the stack).
    let mut stack = vec![(f, 0usize)];
    match state.get(&f) {
        Some(_) => return Ok(()),
        None => {
            state.insert(f, 1);
        }
    }
    while let Some((node, i)) = stack.pop() {
        let callees = calls.get(&node).map(|v| v.as_slice()).unwrap_or(&[]);
        if i < callees.len() {
            stack.push((node, i + 1));
            let c = callees[i];
            match state.get(&c) {
                Some(1) => {
                    return Err(LowerError::Unsupported {
                        instruction: "OpFunctionCall".into(),
                        offset: 0,
                        reason: format!(
                            "recursion through function %{c} (SPIR-V for Vulkan has none)"
                        ),
                    })
                }
                Some(_) => {}
                None => {
                    state.insert(c, 1);
                    stack.push((c, 0));
                }
            }
        } else {
            state.insert(node, 2);
            order.push(node);
        }
    }
    Ok(())
}
