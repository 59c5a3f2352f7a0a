//! Teardown on the renderer's terms: `Context::shutdown` destroys the context now or names
//! what still holds it, and a recording dropped without `complete()` on the renderer's
//! device is kept — not leaked — until `Context::retire` after the renderer's fence. The
//! renderer then destroys its device under validation, which reports any object vkrt left.

#[path = "../examples/common/host.rs"]
mod host;

mod common;

use host::Host;
use vkrt::gpu::{BindingCache, Buffer, Context, ContextOptions, Recorder, Validation};

#[test]
fn shutdown_names_what_holds_the_context_and_destroys_it_once_nothing_does() {
    let _turn = common::vulkan_turn();
    let ctx = match Context::new(&ContextOptions::for_tests()) {
        Ok(c) => c,
        Err(e) if common::no_gpu_allowed() => return eprintln!("skipped: {e}"),
        Err(e) => panic!("{e}"),
    };
    assert!(ctx.holders().is_empty(), "{:?}", ctx.holders());
    let buffers: Vec<Buffer<u32>> = (0..2)
        .map(|_| Buffer::new(&ctx, "held", 4).unwrap())
        .collect();
    let cache = BindingCache::new(&ctx);
    let clone = ctx.clone();
    let busy = ctx.shutdown().unwrap_err();
    let mut held = busy.held.clone();
    held.sort();
    let mut want = vec![("Buffer", 2), ("BindingCache", 1), ("Context clones", 1)];
    want.sort();
    assert_eq!(held, want, "{busy}");
    assert!(busy.to_string().contains("2 Buffer"), "{busy}");
    drop((buffers, cache, clone));
    let ctx = busy.context;
    assert!(ctx.holders().is_empty(), "{:?}", ctx.holders());
    ctx.shutdown().unwrap();
}

#[test]
fn a_recording_dropped_uncompleted_on_an_adopted_device_waits_for_retire() {
    let _turn = common::vulkan_turn();
    let host = match Host::new(Validation::FromEnv) {
        Ok(h) => h,
        Err(e) if common::no_gpu_allowed() => return eprintln!("skipped: {e}"),
        Err(e) => panic!("{e}"),
    };
    let sink = host.sink.clone();
    // SAFETY: the host's handles; the host outlives the context (shut down below) and only
    // this thread uses the queue.
    let ctx = unsafe { Context::from_raw(host.raw_parts()) }.unwrap();
    let data = Buffer::<u32>::from_slice(&ctx, "data", &[1, 2, 3, 4]).unwrap();
    let copy = Buffer::<u32>::new(&ctx, "copy", 4).unwrap();
    let commands = host.command_buffer().unwrap();
    // SAFETY: the host's command buffer, recording, outside a render pass; the buffers
    // outlive its execution; the renderer waits for its fence before retiring the work.
    let mut rec = unsafe { Recorder::from_raw(&ctx, commands.cmd, 4) }.unwrap();
    rec.scope("copy", |rec| rec.copy(&data, &copy, 4));
    let work = rec.finish().unwrap();
    host.submit_and_wait(commands.cmd).unwrap();
    // The renderer loses track of the work: vkrt neither waits on its device nor leaks.
    drop(work);
    let busy = ctx.shutdown().unwrap_err();
    assert!(
        busy.held.contains(&("retired recordings", 1)),
        "{:?}",
        busy.held
    );
    let ctx = busy.context;
    // SAFETY: the host waited for the command buffer's fence above.
    assert_eq!(unsafe { ctx.retire() }, 1);
    assert_eq!(copy.download().unwrap(), [1, 2, 3, 4]);
    drop((data, copy, commands));
    ctx.shutdown().unwrap();
    // Destroying the device reports any object left on it.
    drop(host);
    let messages = sink.lock().unwrap();
    assert!(messages.is_empty(), "validation messages: {messages:?}");
}
