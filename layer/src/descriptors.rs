//! Descriptors: an acceleration structure is, to a lowered shader, a uniform texel buffer of
//! one RGBA32UI texel holding its address (the view each structure is made with).

use ash::vk;

use crate::device::served;
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

unsafe extern "system" fn update_sets(
    device: vk::Device,
    write_count: u32,
    writes: *const vk::WriteDescriptorSet<'_>,
    copy_count: u32,
    copies: *const vk::CopyDescriptorSet<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        let writes_v: &[vk::WriteDescriptorSet<'_>] = match write_count {
            0 => &[],
            // SAFETY: the application's array of its count.
            n => unsafe { std::slice::from_raw_parts(writes, n as usize) },
        };
        // The texel views of every structure written, kept until the call returns.
        let mut views: Vec<Vec<vk::BufferView>> = Vec::new();
        let mut ours: Vec<vk::WriteDescriptorSet<'_>> = Vec::with_capacity(writes_v.len());
        for w in writes_v {
            let mut w = *w;
            if w.descriptor_type == AS {
                let mut next = w.p_next.cast::<vk::BaseInStructure<'_>>();
                let mut handles: &[vk::AccelerationStructureKHR] = &[];
                let mut rest = std::ptr::null();
                // SAFETY: a valid chain.
                while let Some(n) = unsafe { next.as_ref() } {
                    if n.s_type
                        == vk::StructureType::WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR
                    {
                        // SAFETY: the sType says which struct it is.
                        let a = unsafe {
                            &*next.cast::<vk::WriteDescriptorSetAccelerationStructureKHR<'_>>()
                        };
                        // SAFETY: its array of its count.
                        handles = unsafe {
                            std::slice::from_raw_parts(
                                a.p_acceleration_structures,
                                a.acceleration_structure_count as usize,
                            )
                        };
                        rest = n.p_next;
                    }
                    next = n.p_next;
                }
                let v: Vec<vk::BufferView> = handles
                    .iter()
                    .map(|&h| s.accel.object(h).map_or(vk::BufferView::null(), |o| o.view))
                    .collect();
                w.descriptor_type = TEXEL;
                w.p_texel_buffer_view = v.as_ptr();
                // The structure list was the chain's only struct the driver cannot read.
                w.p_next = rest.cast();
                views.push(v);
            }
            ours.push(w);
        }
        // SAFETY: the application's arguments, structures written as their texel views.
        unsafe {
            (s.fns.fp_v1_0().update_descriptor_sets)(
                device,
                write_count,
                ours.as_ptr(),
                copy_count,
                copies,
            )
        };
    })
}
