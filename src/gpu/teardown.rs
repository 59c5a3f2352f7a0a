//! Tearing a context down on the renderer's schedule: what still holds it, by kind
//! ([`Context::holders`]), its destruction now or an answer naming them
//! ([`Context::shutdown`]), and the recordings dropped uncompleted on an adopted device,
//! kept until the renderer says its fence has passed ([`Context::retire`]).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use super::context::Context;
use super::recorder::Recorder;

/// The kinds of vkrt objects that hold a clone of their context.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Holder {
    Buffer,
    TexelView,
    Recorder,
    BindingCache,
    ForeignKernel,
    DriverStructure,
    CompactedSizeQuery,
}

impl Holder {
    pub(crate) const COUNT: usize = 7;

    const NAMES: [&'static str; Self::COUNT] = [
        "Buffer",
        "TexelView",
        "Recorder or RecordedWork",
        "BindingCache",
        "ForeignKernel",
        "AccelerationStructure",
        "CompactedSizeQuery",
    ];
}

/// Live holders by kind, kept in the context.
#[derive(Default)]
pub(crate) struct HolderCounts([AtomicUsize; Holder::COUNT]);

/// A clone of a context that counts itself under its holder's kind while it lives: the
/// field through which a vkrt object keeps its context.
pub(crate) struct Held {
    ctx: Context,
    kind: Holder,
}

impl Held {
    pub(crate) fn new(ctx: &Context, kind: Holder) -> Self {
        ctx.inner.holders.0[kind as usize].fetch_add(1, Ordering::Relaxed);
        Self {
            ctx: ctx.clone(),
            kind,
        }
    }
}

impl Clone for Held {
    fn clone(&self) -> Self {
        Self::new(&self.ctx, self.kind)
    }
}

impl std::ops::Deref for Held {
    type Target = Context;
    fn deref(&self) -> &Context {
        &self.ctx
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        self.ctx.inner.holders.0[self.kind as usize].fetch_sub(1, Ordering::Relaxed);
    }
}

/// [`Context::shutdown`]'s answer while something still holds the context: the context back,
/// and what holds it.
pub struct Busy {
    /// The context, to shut down again once the holders are gone.
    pub context: Context,
    /// What holds it besides this handle, by kind, with how many of each: vkrt's objects
    /// (`"Buffer"`, `"BindingCache"`, ...), `"retired recordings"` ([`Context::retire`]) and
    /// `"Context clones"` (the caller's own).
    pub held: Vec<(&'static str, usize)>,
}

impl std::fmt::Debug for Busy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Busy").field("held", &self.held).finish()
    }
}

impl std::fmt::Display for Busy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the context is still held by")?;
        for (i, (what, n)) in self.held.iter().enumerate() {
            let sep = if i == 0 { " " } else { ", " };
            write!(f, "{sep}{n} {what}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Busy {}

impl Context {
    /// What holds this context besides this handle, by kind (those with none left out): vkrt
    /// objects made from it, recordings waiting for [`Context::retire`], and other clones of
    /// the handle. Empty: [`Context::shutdown`] would destroy it now.
    pub fn holders(&self) -> Vec<(&'static str, usize)> {
        let counts = &self.inner.holders.0;
        let mut held: Vec<(&'static str, usize)> = Holder::NAMES
            .iter()
            .zip(counts)
            .map(|(&name, n)| (name, n.load(Ordering::Relaxed)))
            .collect();
        let objects: usize = held.iter().map(|h| h.1).sum();
        let retired = super::error::lock(&self.inner.retired).len();
        // A retired recording is named as such, not as a live recorder.
        held[Holder::Recorder as usize].1 -= retired.min(held[Holder::Recorder as usize].1);
        held.push(("retired recordings", retired));
        // Every vkrt object holds one clone; what remains beyond this handle is the caller's.
        let clones = Arc::strong_count(&self.inner).saturating_sub(1 + objects);
        held.push(("Context clones", clones));
        held.retain(|h| h.1 > 0);
        held
    }

    /// Destroys the context now — its kernels, pipeline cache and allocator, and the device
    /// and instance where vkrt created them — if this is its last handle; else gives it back
    /// with what still holds it ([`Busy`]), destroying nothing. A renderer calls it at
    /// teardown, before destroying its device, to know vkrt is gone rather than guess.
    pub fn shutdown(self) -> std::result::Result<(), Busy> {
        match Arc::try_unwrap(self.inner) {
            Ok(inner) => {
                drop(inner);
                Ok(())
            }
            Err(inner) => {
                let context = Context { inner };
                let held = context.holders();
                Err(Busy { context, held })
            }
        }
    }

    /// Frees what the recordings dropped without [`RecordedWork::complete`] on this adopted
    /// device still hold (descriptor sets, views, queries, staging buffers), which vkrt keeps
    /// rather than wait on the renderer's device; the number of recordings freed. Call it after
    /// the fence of the renderer's last submission that carried them.
    ///
    /// [`RecordedWork::complete`]: crate::gpu::RecordedWork::complete
    ///
    /// # Safety
    /// Every command buffer vkrt recorded into whose `RecordedWork` was dropped uncompleted
    /// before this call has finished executing (or was never submitted), and is not
    /// submitted again.
    pub unsafe fn retire(&self) -> usize {
        let retired = std::mem::take(&mut *super::error::lock(&self.inner.retired));
        let n = retired.len();
        // Dropped outside the lock: each recorder frees what it recorded with.
        drop(retired);
        n
    }

    /// Keeps `recorder` (whose command buffer may still execute) until [`Context::retire`].
    pub(crate) fn keep_until_retired(&self, recorder: Recorder) {
        super::error::lock(&self.inner.retired).push(recorder);
    }
}
