//! Which public types may cross threads, as `docs/versioning.md` states it. A type that
//! gains or loses `Send` or `Sync` stops this file compiling, so the docs cannot drift.

use vkrt::accel::driver::DriverAccel;
use vkrt::accel::embedded::BuildStatus;
use vkrt::accel::instances::{Instance, TopLevel, TopLevelBuilder};
use vkrt::gpu::{Profile, RecordedWork};
use vkrt::trace::gpu::TraceBatch;
use vkrt::{
    AccelBuilder, AccelChoice, AccelKind, AccelSizes, AccelStructure, Buffer, BuildFlags, Context,
    ContextOptions, DeviceInfo, Geometry, GpuError, GpuGeometry, Hit, RawBuffer, RawParts, Ray,
    Recorder, Scene, TraceGeometry, TraceOptions, Tracer, Validation,
};

fn send_and_sync<T: Send + Sync>() {}

/// Compiles only where `$t` is not `Send` (or not `Sync`): were it, both impls would apply
/// and the call would be ambiguous (the pattern of `static_assertions::assert_not_impl_any`).
macro_rules! assert_not {
    ($marker:path, $t:ty) => {{
        trait AmbiguousIfImpl<A> {
            fn check() {}
        }
        impl<T: ?Sized> AmbiguousIfImpl<()> for T {}
        #[allow(dead_code)]
        struct Invalid;
        impl<T: ?Sized + $marker> AmbiguousIfImpl<Invalid> for T {}
        <$t as AmbiguousIfImpl<_>>::check();
    }};
}

#[test]
fn shared_types_are_send_and_sync() {
    // The device and what lives on it: clone a `Context` into each thread, or share one.
    send_and_sync::<Context>();
    send_and_sync::<ContextOptions>();
    send_and_sync::<DeviceInfo>();
    send_and_sync::<RawParts>();
    send_and_sync::<Validation>();
    send_and_sync::<GpuError>();
    send_and_sync::<Buffer<u32>>();
    // Shared by the recordings of every frame in flight.
    send_and_sync::<vkrt::gpu::BindingCache>();
    send_and_sync::<RawBuffer>();
    send_and_sync::<Profile>();
    // Structures, their builders and inputs.
    send_and_sync::<AccelBuilder>();
    send_and_sync::<AccelStructure>();
    send_and_sync::<AccelSizes>();
    send_and_sync::<AccelChoice>();
    send_and_sync::<AccelKind>();
    send_and_sync::<BuildFlags>();
    send_and_sync::<BuildStatus>();
    send_and_sync::<Geometry>();
    send_and_sync::<GpuGeometry>();
    send_and_sync::<TraceGeometry>();
    send_and_sync::<TopLevelBuilder>();
    send_and_sync::<TopLevel>();
    send_and_sync::<Instance>();
    send_and_sync::<DriverAccel>();
    // Tracing and scenes.
    send_and_sync::<Tracer>();
    send_and_sync::<TraceBatch>();
    send_and_sync::<TraceOptions>();
    send_and_sync::<Ray>();
    send_and_sync::<Hit>();
    send_and_sync::<Scene>();
}

fn send<T: Send>() {}

#[test]
fn recordings_move_between_threads_but_are_not_shared() {
    // Like a command buffer: recorded on one thread, completed on another, used by one
    // thread at a time.
    send::<Recorder>();
    send::<RecordedWork>();
    assert_not!(Sync, Recorder);
    assert_not!(Sync, RecordedWork);
}
