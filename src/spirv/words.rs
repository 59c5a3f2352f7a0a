//! The module as words: its header, where each instruction begins, and what the pass
//! refuses before it parses anything.

use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{Capability, ExecutionMode, ExecutionModel, Op};
use std::collections::HashSet;

use super::LowerError;

const MAGIC: u32 = 0x0723_0203;
const OP_CAPABILITY: u32 = 17;

/// What a first look at the words found.
pub(crate) struct Scan {
    pub version: (u32, u32),
    pub bound: u32,
    /// Whether the module declares `RayQueryKHR` (or the provisional capability).
    pub ray_queries: bool,
    /// Each instruction's opcode and word offset, in the order of the words (filled by
    /// [`scan_all`]).
    pub offsets: Vec<(u32, usize)>,
}

impl Scan {
    /// The word offset of the `index`-th instruction of the module, where the parsed
    /// module's order (`Module::all_inst_iter`) matches the words'.
    pub fn offset_of(&self, index: usize, opcode: u32) -> usize {
        match self.offsets.get(index) {
            Some(&(op, offset)) if op == opcode => offset,
            _ => 0,
        }
    }
}

/// Whether `words` is a SPIR-V module whose leading capabilities include `RayQueryKHR`:
/// the cheap test of whether [`super::lower_ray_queries`] has anything to do.
pub fn has_ray_queries(words: &[u32]) -> bool {
    scan(words).is_ok_and(|s| s.ray_queries)
}

/// The header, and the leading `OpCapability` instructions only.
pub(crate) fn scan(words: &[u32]) -> Result<Scan, LowerError> {
    if words.len() < 5 {
        return Err(LowerError::NotSpirv(format!(
            "{} words, fewer than a header's 5",
            words.len()
        )));
    }
    if words[0] != MAGIC {
        return Err(LowerError::NotSpirv(if words[0] == MAGIC.swap_bytes() {
            "the words are byte-swapped (the magic number reads 0x03022307)".into()
        } else {
            format!(
                "the first word is {:#010x}, not the magic number 0x07230203",
                words[0]
            )
        }));
    }
    let version = ((words[1] >> 16) & 0xff, (words[1] >> 8) & 0xff);
    let mut ray_queries = false;
    let mut i = 5;
    while i < words.len() && (words[i] & 0xffff) == OP_CAPABILITY {
        let count = (words[i] >> 16) as usize;
        if count < 2 || i + count > words.len() {
            break;
        }
        let cap = words[i + 1];
        if cap == Capability::RayQueryKHR as u32 || cap == Capability::RayQueryProvisionalKHR as u32
        {
            ray_queries = true;
        }
        i += count;
    }
    Ok(Scan {
        version,
        bound: words[3],
        ray_queries,
        offsets: Vec::new(),
    })
}

/// Every instruction's place, the version, and what the pass refuses: ray-tracing
/// pipeline stages, capabilities and instructions, and opacity micromaps.
pub(crate) fn scan_all(words: &[u32], mut scan: Scan) -> Result<Scan, LowerError> {
    let (major, minor) = scan.version;
    if major != 1 || !(3..=6).contains(&minor) {
        return Err(LowerError::Version { major, minor });
    }
    if scan.bound == 0 || scan.bound > 0x0040_0000 {
        return Err(LowerError::NotSpirv(format!(
            "id bound {} (a module's ids lie in 1..bound, at most 4,194,304)",
            scan.bound
        )));
    }
    let mut i = 5;
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let opcode = words[i] & 0xffff;
        if count == 0 {
            return Err(LowerError::Malformed {
                offset: i,
                reason: format!("{} has a word count of 0", op_name(opcode)),
            });
        }
        if i + count > words.len() {
            return Err(LowerError::Malformed {
                offset: i,
                reason: format!(
                    "{} of {count} words runs past the module's end ({} words): truncated",
                    op_name(opcode),
                    words.len()
                ),
            });
        }
        refuse(opcode, &words[i + 1..i + count], i)?;
        scan.offsets.push((opcode, i));
        i += count;
    }
    Ok(scan)
}

/// The instruction's name, as the specification writes it.
pub(crate) fn op_name(opcode: u32) -> String {
    match rspirv::grammar::INSTRUCTION_TABLE.lookup_opcode(opcode) {
        Some(inst) => format!("Op{}", inst.opname),
        _ => format!("opcode {opcode}"),
    }
}

fn refuse(opcode: u32, operands: &[u32], offset: usize) -> Result<(), LowerError> {
    let unsupported = |instruction: String, reason: &str| LowerError::Unsupported {
        instruction,
        offset,
        reason: reason.to_string(),
    };
    if opcode == OP_CAPABILITY {
        let cap = operands.first().copied().unwrap_or(0);
        let refused = [
            (
                Capability::RayTracingKHR,
                "ray-tracing pipelines are not lowered",
            ),
            (
                Capability::RayTracingNV,
                "ray-tracing pipelines are not lowered",
            ),
            (
                Capability::RayTracingProvisionalKHR,
                "ray-tracing pipelines are not lowered",
            ),
            (
                Capability::RayTracingMotionBlurNV,
                "motion-blurred ray tracing is not lowered",
            ),
            (
                Capability::RayTracingOpacityMicromapEXT,
                "opacity micromaps are not served",
            ),
            (
                Capability::RayTracingPositionFetchKHR,
                "position fetch in ray-tracing pipelines is not lowered",
            ),
            (
                Capability::ShaderInvocationReorderNV,
                "hit objects are not served",
            ),
        ];
        if let Some((c, why)) = refused.iter().find(|(c, _)| *c as u32 == cap) {
            return Err(unsupported(format!("OpCapability {c:?}"), why));
        }
    }
    if opcode == Op::EntryPoint as u32 {
        let model = operands.first().copied().unwrap_or(u32::MAX);
        let rt = [
            ExecutionModel::RayGenerationKHR,
            ExecutionModel::IntersectionKHR,
            ExecutionModel::AnyHitKHR,
            ExecutionModel::ClosestHitKHR,
            ExecutionModel::MissKHR,
            ExecutionModel::CallableKHR,
        ];
        if let Some(m) = rt.iter().find(|m| **m as u32 == model) {
            return Err(unsupported(
                format!("OpEntryPoint {m:?}"),
                "ray-tracing pipeline stages are not lowered: compute, fragment, vertex, \
                 tessellation, geometry, task and mesh shaders are",
            ));
        }
    }
    let refused_ops = [
        Op::TraceRayKHR,
        Op::ExecuteCallableKHR,
        Op::ReportIntersectionKHR,
        Op::IgnoreIntersectionKHR,
        Op::TerminateRayKHR,
        Op::TraceNV,
        Op::TraceMotionNV,
        Op::TraceRayMotionNV,
        Op::ExecuteCallableNV,
        Op::TypeHitObjectNV,
        Op::RayQueryGetClusterIdNV,
    ];
    if refused_ops.iter().any(|op| *op as u32 == opcode) {
        return Err(unsupported(
            op_name(opcode),
            "an instruction the pass does not serve (ray-tracing pipelines and hit objects \
             are not lowered)",
        ));
    }
    Ok(())
}

/// Every id a parsed module names lies in 1..bound, every result id is defined once, and
/// every id an instruction reads is defined somewhere.
pub(crate) fn check_ids(module: &Module, scan: &Scan) -> Result<(), LowerError> {
    let mut defined = HashSet::new();
    // Forward references are legal in SPIR-V (branches, phis, names, decorations), so
    // definitions are gathered first.
    for (index, inst) in module.all_inst_iter().enumerate() {
        if let Some(id) = inst.result_id {
            let bad = |reason: &str| LowerError::BadId {
                instruction: format!("Op{}", inst.class.opname),
                offset: scan.offset_of(index, inst.class.opcode as u32),
                id,
                reason: reason.into(),
            };
            if id == 0 || id >= scan.bound {
                return Err(bad("a result id outside the module's bound"));
            }
            if !defined.insert(id) {
                return Err(bad("a result id defined twice"));
            }
        }
    }
    // OpTypeForwardPointer declares its pointer without a result id.
    for inst in module.types_global_values.iter() {
        if inst.class.opcode == Op::TypeForwardPointer {
            if let Some(Operand::IdRef(id)) = inst.operands.first() {
                defined.insert(*id);
            }
        }
    }
    for (index, inst) in module.all_inst_iter().enumerate() {
        let ids = inst
            .result_type
            .into_iter()
            .chain(inst.operands.iter().filter_map(|o| match o {
                Operand::IdRef(id) | Operand::IdScope(id) | Operand::IdMemorySemantics(id) => {
                    Some(*id)
                }
                _ => None,
            }));
        for id in ids {
            let reason = if id == 0 || id >= scan.bound {
                "an id outside the module's bound"
            } else if !defined.contains(&id) {
                "an id no instruction defines"
            } else {
                continue;
            };
            return Err(LowerError::BadId {
                instruction: format!("Op{}", inst.class.opname),
                offset: scan.offset_of(index, inst.class.opcode as u32),
                id,
                reason: reason.into(),
            });
        }
    }
    Ok(())
}

/// The module without its `OpExecutionModeId` instructions, and those as instructions (an
/// entry point, a mode and ids), which rspirv's loader does not place.
pub(crate) fn split_execution_mode_ids(
    words: &[u32],
    scan: &Scan,
) -> Result<(Vec<u32>, Vec<Instruction>), LowerError> {
    let mut rest = Vec::with_capacity(words.len());
    rest.extend_from_slice(&words[..5]);
    let mut modes = Vec::new();
    for (k, &(opcode, offset)) in scan.offsets.iter().enumerate() {
        let end = scan.offsets.get(k + 1).map_or(words.len(), |n| n.1);
        let inst = &words[offset..end];
        if opcode != Op::ExecutionModeId as u32 {
            rest.extend_from_slice(inst);
            continue;
        }
        let mode = inst
            .get(2)
            .and_then(|m| ExecutionMode::from_u32(*m))
            .ok_or_else(|| LowerError::Malformed {
                offset,
                reason: "OpExecutionModeId without a known execution mode".into(),
            })?;
        let mut operands = vec![Operand::IdRef(inst[1]), Operand::ExecutionMode(mode)];
        operands.extend(inst[3..].iter().map(|id| Operand::IdRef(*id)));
        modes.push(Instruction::new(Op::ExecutionModeId, None, None, operands));
    }
    Ok((rest, modes))
}
