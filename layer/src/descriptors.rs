//! Descriptors: an acceleration structure is, to a lowered shader, a uniform texel buffer of
//! one RGBA32UI texel holding its address (the view each structure is made with) — in set
//! layouts, pools, writes, update templates and push descriptors.

use ash::vk;

use crate::commands::slice;
use crate::device::{served, Served};
use crate::{guard, pfn};

const AS: vk::DescriptorType = vk::DescriptorType::ACCELERATION_STRUCTURE_KHR;
const TEXEL: vk::DescriptorType = vk::DescriptorType::UNIFORM_TEXEL_BUFFER;

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateDescriptorSetLayout" => {
            pfn!(create_set_layout, vk::PFN_vkCreateDescriptorSetLayout)
        }
        b"vkGetDescriptorSetLayoutSupport" | b"vkGetDescriptorSetLayoutSupportKHR" => {
            pfn!(set_layout_support, vk::PFN_vkGetDescriptorSetLayoutSupport)
        }
        b"vkCreateDescriptorPool" => pfn!(create_pool, vk::PFN_vkCreateDescriptorPool),
        b"vkUpdateDescriptorSets" => pfn!(update_sets, vk::PFN_vkUpdateDescriptorSets),
        b"vkCmdPushDescriptorSetKHR" | b"vkCmdPushDescriptorSet" => {
            pfn!(cmd_push_descriptor_set, vk::PFN_vkCmdPushDescriptorSetKHR)
        }
        b"vkCmdPushDescriptorSetWithTemplateKHR" | b"vkCmdPushDescriptorSetWithTemplate" => pfn!(
            cmd_push_descriptor_set_with_template,
            vk::PFN_vkCmdPushDescriptorSetWithTemplateKHR
        ),
        b"vkCreateDescriptorUpdateTemplate" | b"vkCreateDescriptorUpdateTemplateKHR" => {
            pfn!(
                create_update_template,
                vk::PFN_vkCreateDescriptorUpdateTemplate
            )
        }
        b"vkDestroyDescriptorUpdateTemplate" | b"vkDestroyDescriptorUpdateTemplateKHR" => {
            pfn!(
                destroy_update_template,
                vk::PFN_vkDestroyDescriptorUpdateTemplate
            )
        }
        b"vkUpdateDescriptorSetWithTemplate" | b"vkUpdateDescriptorSetWithTemplateKHR" => {
            pfn!(
                update_with_template,
                vk::PFN_vkUpdateDescriptorSetWithTemplate
            )
        }
        _ => None,
    }
}

/// `bindings` with structures as texel buffers.
///
/// # Safety
/// `p` holds `n` bindings.
unsafe fn translated_bindings<'a>(
    p: *const vk::DescriptorSetLayoutBinding<'a>,
    n: u32,
) -> Vec<vk::DescriptorSetLayoutBinding<'a>> {
    if n == 0 {
        return Vec::new();
    }
    // SAFETY: the caller's contract.
    unsafe { std::slice::from_raw_parts(p, n as usize) }
        .iter()
        .map(|b| {
            let mut b = *b;
            if b.descriptor_type == AS {
                b.descriptor_type = TEXEL;
            }
            b
        })
        .collect()
}

unsafe extern "system" fn create_set_layout(
    device: vk::Device,
    info: *const vk::DescriptorSetLayoutCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::DescriptorSetLayout,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        // SAFETY: as above.
        let bindings = unsafe { translated_bindings(ours.p_bindings, ours.binding_count) };
        ours.p_bindings = bindings.as_ptr();
        // SAFETY: the application's arguments, structures translated.
        unsafe { (s.fns.fp_v1_0().create_descriptor_set_layout)(device, &ours, allocator, out) }
    })
}

unsafe extern "system" fn set_layout_support(
    device: vk::Device,
    info: *const vk::DescriptorSetLayoutCreateInfo<'_>,
    out: *mut vk::DescriptorSetLayoutSupport<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        // SAFETY: as above.
        let bindings = unsafe { translated_bindings(ours.p_bindings, ours.binding_count) };
        ours.p_bindings = bindings.as_ptr();
        // SAFETY: the application's arguments, structures translated.
        unsafe { (s.fns.fp_v1_1().get_descriptor_set_layout_support)(device, &ours, out) };
    })
}

unsafe extern "system" fn create_pool(
    device: vk::Device,
    info: *const vk::DescriptorPoolCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::DescriptorPool,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        let sizes: Vec<vk::DescriptorPoolSize> = match ours.pool_size_count {
            0 => Vec::new(),
            // SAFETY: as above.
            n => unsafe { std::slice::from_raw_parts(ours.p_pool_sizes, n as usize) }
                .iter()
                .map(|p| vk::DescriptorPoolSize {
                    ty: if p.ty == AS { TEXEL } else { p.ty },
                    ..*p
                })
                .collect(),
        };
        ours.p_pool_sizes = sizes.as_ptr();
        // SAFETY: the application's arguments, structures translated.
        unsafe { (s.fns.fp_v1_0().create_descriptor_pool)(device, &ours, allocator, out) }
    })
}

/// Writes with their structures as texel views, and the views they point to (kept with
/// them until the call that takes them returns).
struct Writes<'a> {
    writes: Vec<vk::WriteDescriptorSet<'a>>,
    _views: Vec<Vec<vk::BufferView>>,
}

/// # Safety
/// `writes` and their chains are valid.
unsafe fn translate_writes<'a>(s: &Served, writes: &[vk::WriteDescriptorSet<'a>]) -> Writes<'a> {
    let mut views: Vec<Vec<vk::BufferView>> = Vec::new();
    let mut ours: Vec<vk::WriteDescriptorSet<'_>> = Vec::with_capacity(writes.len());
    for w in writes {
        let mut w = *w;
        if w.descriptor_type == AS {
            let mut next = w.p_next.cast::<vk::BaseInStructure<'_>>();
            let mut handles: &[vk::AccelerationStructureKHR] = &[];
            let mut rest = std::ptr::null();
            // SAFETY: a valid chain.
            while let Some(n) = unsafe { next.as_ref() } {
                if n.s_type == vk::StructureType::WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR {
                    // SAFETY: the sType says which struct it is.
                    let a = unsafe {
                        &*next.cast::<vk::WriteDescriptorSetAccelerationStructureKHR<'_>>()
                    };
                    // SAFETY: its array of its count.
                    handles = unsafe {
                        slice(a.p_acceleration_structures, a.acceleration_structure_count)
                    };
                    rest = n.p_next;
                }
                next = n.p_next;
            }
            let v: Vec<vk::BufferView> = handles.iter().map(|&h| view_of(s, h)).collect();
            w.descriptor_type = TEXEL;
            w.p_texel_buffer_view = v.as_ptr();
            // The structure list was the chain's only struct the driver cannot read.
            w.p_next = rest.cast();
            views.push(v);
        }
        ours.push(w);
    }
    Writes {
        writes: ours,
        _views: views,
    }
}

/// The texel view a structure is written as (null for a null or unknown handle: the walk
/// then finds no structure, as for a null descriptor).
fn view_of(s: &Served, h: vk::AccelerationStructureKHR) -> vk::BufferView {
    s.accel.object(h).map_or(vk::BufferView::null(), |o| o.view)
}

unsafe extern "system" fn update_sets(
    device: vk::Device,
    write_count: u32,
    writes: *const vk::WriteDescriptorSet<'_>,
    copy_count: u32,
    copies: *const vk::CopyDescriptorSet<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        // SAFETY: the application's array of its count.
        let ours = unsafe { translate_writes(&s, slice(writes, write_count)) };
        // SAFETY: the application's arguments, structures written as their texel views.
        unsafe {
            (s.fns.fp_v1_0().update_descriptor_sets)(
                device,
                write_count,
                ours.writes.as_ptr(),
                copy_count,
                copies,
            )
        };
    })
}

unsafe extern "system" fn cmd_push_descriptor_set(
    cb: vk::CommandBuffer,
    point: vk::PipelineBindPoint,
    layout: vk::PipelineLayout,
    set: u32,
    count: u32,
    writes: *const vk::WriteDescriptorSet<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.descriptor_fns.push_descriptor_set else {
            return;
        };
        // SAFETY: the application's array of its count.
        let ours = unsafe { translate_writes(&s, slice(writes, count)) };
        if point == vk::PipelineBindPoint::COMPUTE {
            crate::commands::note_push_descriptors(&s, cb, layout, set, &ours.writes);
        }
        // SAFETY: the application's call, structures as their texel views.
        unsafe { f(cb, point, layout, set, count, ours.writes.as_ptr()) };
    })
}

/// An update template the application created: its structure entries, (offset, stride,
/// count) of handles in the data it passes, which become view handles at the same places
/// (both 8 bytes).
pub struct Template {
    structures: Vec<(usize, usize, u32)>,
    /// Bytes the data spans (the farthest entry's end).
    span: usize,
    /// Whether it pushes descriptors at the compute bind point (what a build in the same
    /// command buffer must push again).
    compute_push: bool,
}

/// Whether `template` is alive (the application has not destroyed it).
pub fn template_alive(template: vk::DescriptorUpdateTemplate) -> bool {
    TEMPLATES.lock().is_ok_and(|m| m.contains_key(&template))
}

static TEMPLATES: std::sync::LazyLock<
    std::sync::Mutex<std::collections::HashMap<vk::DescriptorUpdateTemplate, Template>>,
> = std::sync::LazyLock::new(Default::default);

unsafe extern "system" fn create_update_template(
    device: vk::Device,
    info: *const vk::DescriptorUpdateTemplateCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::DescriptorUpdateTemplate,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        let Some(f) = s.descriptor_fns.create_update_template else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info and its entries.
        let mut ours = unsafe { *info };
        // SAFETY: as above.
        let entries = unsafe {
            slice(
                ours.p_descriptor_update_entries,
                ours.descriptor_update_entry_count,
            )
        };
        let mut structures = Vec::new();
        let mut span = 0;
        let translated: Vec<vk::DescriptorUpdateTemplateEntry> = entries
            .iter()
            .map(|e| {
                let size = match e.descriptor_type {
                    vk::DescriptorType::SAMPLER
                    | vk::DescriptorType::COMBINED_IMAGE_SAMPLER
                    | vk::DescriptorType::SAMPLED_IMAGE
                    | vk::DescriptorType::STORAGE_IMAGE
                    | vk::DescriptorType::INPUT_ATTACHMENT => {
                        std::mem::size_of::<vk::DescriptorImageInfo>()
                    }
                    vk::DescriptorType::UNIFORM_BUFFER
                    | vk::DescriptorType::STORAGE_BUFFER
                    | vk::DescriptorType::UNIFORM_BUFFER_DYNAMIC
                    | vk::DescriptorType::STORAGE_BUFFER_DYNAMIC => {
                        std::mem::size_of::<vk::DescriptorBufferInfo>()
                    }
                    // Inline uniform blocks: the count is bytes.
                    vk::DescriptorType::INLINE_UNIFORM_BLOCK => 1,
                    _ => 8,
                };
                if e.descriptor_count > 0 {
                    span = span.max(e.offset + e.stride * (e.descriptor_count as usize - 1) + size);
                }
                let mut e = *e;
                if e.descriptor_type == AS {
                    structures.push((e.offset, e.stride, e.descriptor_count));
                    e.descriptor_type = TEXEL;
                }
                e
            })
            .collect();
        ours.p_descriptor_update_entries = translated.as_ptr();
        // SAFETY: the application's call, its structure entries as texel buffers.
        let r = unsafe { f(device, &ours, allocator, out) };
        if r == vk::Result::SUCCESS {
            let compute_push = ours.template_type
                == vk::DescriptorUpdateTemplateType::PUSH_DESCRIPTORS_KHR
                && ours.pipeline_bind_point == vk::PipelineBindPoint::COMPUTE;
            // SAFETY: created above.
            let t = unsafe { *out };
            TEMPLATES
                .lock()
                .map(|mut m| {
                    m.insert(
                        t,
                        Template {
                            structures,
                            span,
                            compute_push,
                        },
                    )
                })
                .ok();
        }
        r
    })
}

unsafe extern "system" fn destroy_update_template(
    device: vk::Device,
    template: vk::DescriptorUpdateTemplate,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        TEMPLATES.lock().map(|mut m| m.remove(&template)).ok();
        if let Some(f) = s.descriptor_fns.destroy_update_template {
            // SAFETY: the application's call, passed on.
            unsafe { f(device, template, allocator) };
        }
    })
}

/// Runs `f` on the layer's record of `template`, under one lock of the records.
fn with_template<R>(
    template: vk::DescriptorUpdateTemplate,
    f: impl FnOnce(&Template) -> R,
) -> Option<R> {
    let templates = TEMPLATES.lock().ok()?;
    Some(f(templates.get(&template)?))
}

/// The application's template data with its structure handles replaced by their views,
/// where `t` has structure entries.
///
/// # Safety
/// `data` holds what the template's entries read.
unsafe fn translated(s: &Served, t: &Template, data: *const std::ffi::c_void) -> Option<Vec<u8>> {
    if t.structures.is_empty() {
        return None;
    }
    // SAFETY: the caller's contract: the entries' span.
    let mut bytes = unsafe { std::slice::from_raw_parts(data.cast::<u8>(), t.span) }.to_vec();
    for &(offset, stride, count) in &t.structures {
        for k in 0..count as usize {
            let at = offset + k * stride;
            let raw = u64::from_le_bytes(bytes[at..at + 8].try_into().ok()?);
            let view = view_of(s, vk::Handle::from_raw(raw));
            bytes[at..at + 8].copy_from_slice(&vk::Handle::as_raw(view).to_le_bytes());
        }
    }
    Some(bytes)
}

unsafe extern "system" fn update_with_template(
    device: vk::Device,
    set: vk::DescriptorSet,
    template: vk::DescriptorUpdateTemplate,
    data: *const std::ffi::c_void,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        let Some(f) = s.descriptor_fns.update_with_template else {
            return;
        };
        // SAFETY: the application's data for this template.
        let ours = with_template(template, |t| unsafe { translated(&s, t, data) }).flatten();
        let data = ours.as_ref().map_or(data, |b| b.as_ptr().cast());
        // SAFETY: the application's call, its structures as their views.
        unsafe { f(device, set, template, data) };
    })
}

unsafe extern "system" fn cmd_push_descriptor_set_with_template(
    cb: vk::CommandBuffer,
    template: vk::DescriptorUpdateTemplate,
    layout: vk::PipelineLayout,
    set: u32,
    data: *const std::ffi::c_void,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.descriptor_fns.push_descriptor_set_with_template else {
            return;
        };
        // The data with its structures as views, and a compute push's bytes kept, to push
        // again after a build in this command buffer.
        let (ours, kept) = with_template(template, |t| {
            // SAFETY: the application's data for this template.
            let ours = unsafe { translated(&s, t, data) };
            let kept = t.compute_push.then(|| match &ours {
                Some(b) => b.clone(),
                // SAFETY: the data spans what the template's entries read.
                None => unsafe { std::slice::from_raw_parts(data.cast::<u8>(), t.span) }.to_vec(),
            });
            (ours, kept)
        })
        .unwrap_or_default();
        let data = ours.as_ref().map_or(data, |b| b.as_ptr().cast());
        if let Some(bytes) = kept {
            crate::commands::note_push_template(&s, cb, template, layout, set, bytes);
        }
        // SAFETY: the application's call, its structures as their views.
        unsafe { f(cb, template, layout, set, data) };
    })
}

/// The descriptor entry points the layer translates that a device may lack (templates are
/// core 1.1; push descriptors `VK_KHR_push_descriptor`).
#[derive(Default)]
pub struct DescriptorFns {
    pub push_descriptor_set: Option<vk::PFN_vkCmdPushDescriptorSetKHR>,
    pub push_descriptor_set_with_template: Option<vk::PFN_vkCmdPushDescriptorSetWithTemplateKHR>,
    pub create_update_template: Option<vk::PFN_vkCreateDescriptorUpdateTemplate>,
    pub destroy_update_template: Option<vk::PFN_vkDestroyDescriptorUpdateTemplate>,
    pub update_with_template: Option<vk::PFN_vkUpdateDescriptorSetWithTemplate>,
}

impl DescriptorFns {
    /// # Safety
    /// `gdpa` is the next layer's `vkGetDeviceProcAddr`, `device` live.
    pub unsafe fn load(gdpa: vk::PFN_vkGetDeviceProcAddr, device: vk::Device) -> Self {
        macro_rules! load {
            ($($name:literal),+; $t:ty) => {
                [$($name),+]
                    .iter()
                    // SAFETY: the next layer's entry point, by name.
                    .find_map(|n: &&std::ffi::CStr| unsafe { gdpa(device, n.as_ptr()) })
                    // SAFETY: the loader's pointer is the function of that name.
                    .map(|f| unsafe { std::mem::transmute::<unsafe extern "system" fn(), $t>(f) })
            };
        }
        Self {
            push_descriptor_set: load!(c"vkCmdPushDescriptorSetKHR", c"vkCmdPushDescriptorSet"; vk::PFN_vkCmdPushDescriptorSetKHR),
            push_descriptor_set_with_template: load!(c"vkCmdPushDescriptorSetWithTemplateKHR", c"vkCmdPushDescriptorSetWithTemplate"; vk::PFN_vkCmdPushDescriptorSetWithTemplateKHR),
            create_update_template: load!(c"vkCreateDescriptorUpdateTemplate", c"vkCreateDescriptorUpdateTemplateKHR"; vk::PFN_vkCreateDescriptorUpdateTemplate),
            destroy_update_template: load!(c"vkDestroyDescriptorUpdateTemplate", c"vkDestroyDescriptorUpdateTemplateKHR"; vk::PFN_vkDestroyDescriptorUpdateTemplate),
            update_with_template: load!(c"vkUpdateDescriptorSetWithTemplate", c"vkUpdateDescriptorSetWithTemplateKHR"; vk::PFN_vkUpdateDescriptorSetWithTemplate),
        }
    }
}
