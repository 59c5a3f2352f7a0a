//! A context vkrt creates, with what the caller's own shader needs beyond vkrt's features
//! (`ContextOptions::extra`): a kernel of the caller's with scalar block layout runs on it,
//! under validation without a message — where a context without the feature gets one — and
//! what the device lacks is `MissingCapability`, before any device is made.

mod common;

use std::ffi::CString;
use vkrt::gpu::{
    vk, Buffer, Context, ContextOptions, ExtraFeatures, ForeignBinding, ForeignKernel, GpuError,
    Recorder,
};

/// `out[i] = in[i].a.x + in[i].b.z`, over 20-byte `{ vec2 a; vec3 b; }` records: scalar
/// layout (`b` straddles a 16-byte boundary, which std430 and relaxed layout forbid).
const SCALAR: &str = r#"#version 460
#extension GL_EXT_scalar_block_layout : require
layout(local_size_x = 64) in;
struct Rec { vec2 a; vec3 b; };
layout(set = 0, binding = 0, scalar) readonly buffer In { Rec recs[]; };
layout(set = 0, binding = 1, std430) writeonly buffer Out { float sums[]; };
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < uint(recs.length())) sums[i] = recs[i].a.x + recs[i].b.z;
}
"#;

fn context(extra: ExtraFeatures) -> Option<vkrt::gpu::Result<Context>> {
    let options = ContextOptions {
        extra,
        ..ContextOptions::for_tests()
    };
    match Context::new(&options) {
        Err(GpuError::Loader(e)) | Err(GpuError::NoDevice(e)) if common::no_gpu_allowed() => {
            eprintln!("skipped: {e}");
            None
        }
        r => Some(r),
    }
}

/// Runs the scalar-layout kernel on `ctx`: the sums, and the validation messages.
fn run(ctx: &Context, spirv: &[u32]) -> (Vec<f32>, Vec<String>) {
    let n = 100;
    let recs: Vec<[f32; 5]> = (0..n)
        .map(|i| [i as f32, 0.25, 0.5, 1.5, 2.0 * i as f32])
        .collect();
    let input = Buffer::from_slice(ctx, "recs", &recs).unwrap();
    let out = Buffer::<f32>::new(ctx, "sums", n).unwrap();
    let kernel = ForeignKernel::new(
        ctx,
        "scalar",
        spirv,
        &[
            ForeignBinding::Storage(&input),
            ForeignBinding::Storage(&out),
        ],
        0,
        &[],
    )
    .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    kernel
        .record_dispatch(&mut rec, (n as u64).div_ceil(64), &[])
        .unwrap();
    rec.submit_and_wait().unwrap();
    let messages = ctx.take_validation_messages();
    (
        out.download().unwrap(),
        messages.iter().map(|m| m.to_string()).collect(),
    )
}

#[test]
fn the_callers_scalar_layout_kernel_runs_on_a_context_with_the_feature() {
    let _turn = common::vulkan_turn();
    let spirv = match common::compile_glsl(SCALAR, &[]) {
        Ok(s) => s,
        Err(e) => panic!("glslc: {e}"),
    };
    let extra = ExtraFeatures {
        v12: vk::PhysicalDeviceVulkan12Features::default().scalar_block_layout(true),
        ..ExtraFeatures::default()
    };
    let Some(ctx) = context(extra) else { return };
    let ctx = ctx.unwrap();
    let (sums, messages) = run(&ctx, &spirv);
    assert!(messages.is_empty(), "validation: {messages:?}");
    let want: Vec<f32> = (0..100).map(|i| i as f32 + 2.0 * i as f32).collect();
    assert_eq!(sums, want);

    // Without it, the layer refuses the module's layout (where the layer runs).
    let plain = context(ExtraFeatures::default()).unwrap().unwrap();
    if plain.validation_enabled() {
        let (_, messages) = run(&plain, &spirv);
        assert!(
            messages.iter().any(|m| m.contains("layout rules")),
            "no message for a scalar-layout shader without the feature: {messages:?}"
        );
    }
}

#[test]
fn an_extra_the_device_lacks_is_missing_capability() {
    let _turn = common::vulkan_turn();
    let extra = ExtraFeatures {
        extensions: vec![CString::new("VK_VKRT_no_such_extension").unwrap()],
        ..ExtraFeatures::default()
    };
    let Some(r) = context(extra) else { return };
    match r {
        Err(GpuError::MissingCapability { what, .. }) => {
            assert!(what.contains("VK_VKRT_no_such_extension"), "{what}")
        }
        other => panic!("{:?}", other.map(|_| ())),
    }
}
