//! The kd-tree node layout is the same in Rust and GLSL: a kernel writes nodes through the
//! GLSL struct and Rust reads them as `KdNode`.

mod common;

use vkrt::accel::kdtree::KdNode;
use vkrt::gpu::{kernels, Buffer, Recorder, Spec};

#[test]
fn glsl_and_rust_kd_nodes_agree() {
    assert_eq!(std::mem::size_of::<KdNode>(), 16);
    assert_eq!(std::mem::offset_of!(KdNode, split), 0);
    assert_eq!(std::mem::offset_of!(KdNode, kind), 4);
    assert_eq!(std::mem::offset_of!(KdNode, a), 8);
    assert_eq!(std::mem::offset_of!(KdNode, b), 12);
    let Some(ctx) = common::context() else { return };
    let n = 100u32;
    let kernel = ctx
        .kernel(
            &kernels::ACCEL_KDTREE_LAYOUT_PROBE,
            &Spec::new().workgroup(64),
        )
        .unwrap();
    let nodes = Buffer::<KdNode>::zeroed(&ctx, "layout.nodes", n as usize).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.dispatch(&kernel, [2, 1, 1], &[&nodes], &n);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    let got = nodes.download().unwrap();
    for (i, node) in got.iter().enumerate() {
        let i = i as u32;
        assert_eq!(
            *node,
            KdNode {
                split: i as f32 * 0.5,
                kind: i % 4,
                a: 3 * i,
                b: 7 * i + 1
            }
        );
    }
    common::assert_silent(&ctx);
}
