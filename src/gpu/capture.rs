//! Commands held back from the command buffer and recorded later, interleaved: how several
//! independent sequences of passes (the builds of a batch, each over its own memory) share
//! their barriers — pass `k` of every sequence, then one barrier, then pass `k + 1` of
//! every sequence — instead of each paying its own.
//!
//! A captured command is what the recorder would have put into the command buffer, with
//! every descriptor set already written and every check already made (a capture fails as
//! the recording would); only the order changes when it is replayed.

use ash::vk;

/// Stages and accesses on one side of a barrier.
pub(crate) type Scope = (vk::PipelineStageFlags, vk::AccessFlags);

/// A barrier's source and destination.
type Barrier = (Scope, Scope);

/// The commands of one pass and the barrier after them (`None`: the last pass).
type Pass = (Vec<Cmd>, Option<Barrier>);

/// One command, as the recorder records it.
#[derive(Clone, Debug)]
pub(crate) enum Cmd {
    /// The pipeline, its descriptor set 0 and push constants (empty: none).
    Bind {
        pipeline: vk::Pipeline,
        layout: vk::PipelineLayout,
        set: SetZero,
        push: Vec<u8>,
    },
    /// A debug label naming the dispatch that follows.
    Label(std::ffi::CString),
    Dispatch([u32; 3]),
    DispatchIndirect {
        buffer: vk::Buffer,
        offset: u64,
    },
    Fill {
        buffer: vk::Buffer,
        offset: u64,
        size: u64,
        value: u32,
    },
    Copy {
        src: vk::Buffer,
        dst: vk::Buffer,
        region: vk::BufferCopy,
    },
    Update {
        buffer: vk::Buffer,
        offset: u64,
        data: Vec<u8>,
    },
    /// A global memory barrier.
    Barrier {
        src: Scope,
        dst: Scope,
    },
}

/// How a kernel's set 0 reaches it.
#[derive(Clone, Debug)]
pub(crate) enum SetZero {
    /// A descriptor set written for its layout.
    Bound(vk::DescriptorSet),
    /// Storage ranges pushed into the command buffer (`VK_KHR_push_descriptor`), by
    /// binding number.
    Pushed(Vec<(u32, vk::DescriptorBufferInfo)>),
}

/// Both barriers in one: every stage and access of either on each side (what either
/// orders, the union orders too).
fn union(a: Barrier, b: Barrier) -> Barrier {
    (
        (a.0 .0 | b.0 .0, a.0 .1 | b.0 .1),
        (a.1 .0 | b.1 .0, a.1 .1 | b.1 .1),
    )
}

/// A sequence cut at its barriers: the commands before each, and the barrier after them
/// (back-to-back barriers merged; `None` after the last commands).
fn passes(list: Vec<Cmd>) -> Vec<Pass> {
    let mut out: Vec<Pass> = Vec::new();
    let mut current = Vec::new();
    for cmd in list {
        match cmd {
            Cmd::Barrier { src, dst } => match out.last_mut() {
                // Nothing since the last barrier: widen it.
                Some((_, Some(b))) if current.is_empty() => *b = union(*b, (src, dst)),
                _ => out.push((std::mem::take(&mut current), Some((src, dst)))),
            },
            cmd => current.push(cmd),
        }
    }
    if !current.is_empty() {
        out.push((current, None));
    }
    out
}

/// The commands of `lists` in one sequence: pass `k` of every list, in list order, then
/// the union of the barriers that end those passes, for every `k`. Each list keeps its own
/// order and at least its own barriers between its passes; commands of different lists
/// meet unordered within a pass (their memory must be disjoint).
pub(crate) fn interleave(lists: Vec<Vec<Cmd>>) -> Vec<Cmd> {
    let cut: Vec<_> = lists.into_iter().map(passes).collect();
    let steps = cut.iter().map(Vec::len).max().unwrap_or(0);
    let mut cut: Vec<_> = cut.into_iter().map(Vec::into_iter).collect();
    let mut out = Vec::new();
    for _ in 0..steps {
        let mut barrier: Option<Barrier> = None;
        for list in &mut cut {
            if let Some((cmds, after)) = list.next() {
                out.extend(cmds);
                barrier = match (barrier, after) {
                    (Some(a), Some(b)) => Some(union(a, b)),
                    (a, b) => a.or(b),
                };
            }
        }
        if let Some((src, dst)) = barrier {
            out.push(Cmd::Barrier { src, dst });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const C: Scope = (
        vk::PipelineStageFlags::COMPUTE_SHADER,
        vk::AccessFlags::SHADER_WRITE,
    );
    const T: Scope = (
        vk::PipelineStageFlags::TRANSFER,
        vk::AccessFlags::TRANSFER_WRITE,
    );

    fn d(x: u32) -> Cmd {
        Cmd::Dispatch([x, 1, 1])
    }

    fn b(src: Scope, dst: Scope) -> Cmd {
        Cmd::Barrier { src, dst }
    }

    fn shape(cmds: &[Cmd]) -> Vec<String> {
        cmds.iter()
            .map(|c| match c {
                Cmd::Dispatch(g) => format!("d{}", g[0]),
                Cmd::Barrier { src, dst } => {
                    format!("b{:?}>{:?}", src.0.as_raw(), dst.0.as_raw())
                }
                _ => "other".into(),
            })
            .collect()
    }

    #[test]
    fn passes_of_every_list_share_one_barrier_each() {
        let a = vec![d(1), b(C, C), d(2), b(T, C), b(C, C), d(3)];
        let b_ = vec![d(10), b(C, C), d(20)];
        let c = vec![d(100)];
        let out = interleave(vec![a, b_, c]);
        let (cs, ts) = (C.0.as_raw(), T.0.as_raw());
        let tc = cs | ts;
        assert_eq!(
            shape(&out),
            [
                "d1".to_string(),
                "d10".into(),
                "d100".into(),
                format!("b{cs}>{cs}"),
                "d2".into(),
                "d20".into(),
                format!("b{tc}>{cs}"),
                "d3".into(),
            ]
        );
    }

    #[test]
    fn one_list_keeps_its_order_and_its_barriers() {
        let a = vec![b(C, C), d(1), b(C, T), d(2), b(C, C)];
        let out = interleave(vec![a]);
        let (cs, ts) = (C.0.as_raw(), T.0.as_raw());
        assert_eq!(
            shape(&out),
            [
                format!("b{cs}>{cs}"),
                "d1".into(),
                format!("b{cs}>{ts}"),
                "d2".into(),
                format!("b{cs}>{cs}"),
            ]
        );
        assert!(interleave(Vec::new()).is_empty());
    }
}
