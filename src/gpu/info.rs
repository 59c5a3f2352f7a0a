//! What a physical device is and can do: the facts `vkrt info` prints and kernels plan by.

use ash::vk;
use serde::Serialize;

use super::error::{GpuError, Result};

/// Optional device features vkrt enables where present.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq, Eq)]
pub struct DeviceFeatures {
    /// `storageBuffer8BitAccess`: 8-bit loads and stores in storage buffers (the GPU
    /// kd-tree builder's 1-byte event flags need it).
    pub storage_buffer_8bit: bool,
    /// `storageBuffer16BitAccess`: 16-bit loads and stores in storage buffers.
    pub storage_buffer_16bit: bool,
    /// `shaderInt8`: 8-bit integer arithmetic in shaders.
    pub shader_int8: bool,
    /// `shaderInt16`: 16-bit integer arithmetic in shaders.
    pub shader_int16: bool,
    /// `shaderInt64`: 64-bit integers in shaders (the exact walk's 64-bit node loads,
    /// 64-bit Morton codes).
    pub shader_int64: bool,
    /// 64-bit atomics on storage buffers: the chained scan publishes (flag, sum) as one word.
    pub shader_buffer_int64_atomics: bool,
    /// Doubles in shaders: the watertight triangle test's exact fallback uses them.
    pub shader_float64: bool,
    /// `shaderFloat16`: 16-bit floats in shaders.
    pub shader_float16: bool,
    /// `hostQueryReset`: query pools may be reset from the host (`vkResetQueryPool`).
    pub host_query_reset: bool,
    /// `pipelineStatisticsQuery`: pipeline-statistics queries, which count each scope's
    /// compute-shader invocations when asked to ([`super::Context::set_pipeline_statistics`]).
    pub pipeline_statistics_query: bool,
    /// `subgroupSizeControl`: a pipeline may ask for a subgroup size between
    /// [`DeviceInfo::min_subgroup_size`] and [`DeviceInfo::max_subgroup_size`].
    pub subgroup_size_control: bool,
    /// `computeFullSubgroups`: a compute pipeline may require every subgroup to be full.
    pub compute_full_subgroups: bool,
    /// The device speaks Vulkan 1.3 (subgroup size control is core there).
    pub api_1_3: bool,
    /// `bufferDeviceAddress`: geometry given to the builders at device addresses
    /// (`accel::geometry::GeometryData::Address`); the driver's structure needs it too.
    pub buffer_device_address: bool,
    /// The driver's own ray tracing from compute shaders: `VK_KHR_acceleration_structure`
    /// (with `VK_KHR_deferred_host_operations`, which it requires) and `VK_KHR_ray_query`,
    /// their features, and `bufferDeviceAddress` (Mesa 25's lavapipe has them; 22.3's not).
    pub ray_query: bool,
    /// The calibrated-timestamps extension the device has enabled, if any: profiles then
    /// put the device's ticks on the host's clock through it ([`super::Calibration`]);
    /// without one, by a timestamp written at a submission.
    pub calibrated_timestamps: Option<CalibratedTimestamps>,
    /// `VK_KHR_push_descriptor`: vkrt's kernels without texel bindings (every builder's)
    /// push their buffers into the command buffer instead of binding a descriptor set, so
    /// recording them creates no descriptor set and needs no [`super::BindingCache`]. A
    /// context vkrt creates enables it only when asked ([`super::ExtraFeatures::extensions`]):
    /// lavapipe runs a pushed dispatch slower than a bound one.
    pub push_descriptor: bool,
}

/// Which calibrated-timestamps extension a device has.
#[derive(Clone, Copy, Debug, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum CalibratedTimestamps {
    /// `VK_KHR_calibrated_timestamps`.
    Khr,
    /// `VK_EXT_calibrated_timestamps`.
    Ext,
}

impl CalibratedTimestamps {
    /// The extension's name.
    pub fn name(self) -> &'static std::ffi::CStr {
        match self {
            Self::Khr => ash::khr::calibrated_timestamps::NAME,
            Self::Ext => ash::ext::calibrated_timestamps::NAME,
        }
    }

    /// The one of `extensions` to use (the KHR one where both are), if any.
    fn among(has: impl Fn(&std::ffi::CStr) -> bool) -> Option<Self> {
        [Self::Khr, Self::Ext].into_iter().find(|c| has(c.name()))
    }
}

impl DeviceFeatures {
    /// The features a device was created with, read from the `VkDeviceCreateInfo` the
    /// renderer gave `vkCreateDevice`: `pEnabledFeatures` or a `VkPhysicalDeviceFeatures2`
    /// in its chain, the Vulkan 1.1, 1.2 and 1.3 feature structs, the per-feature structs
    /// of the extensions promoted into them, the acceleration-structure and ray-query
    /// structs, and its enabled extensions; `api_version` is the device's. What
    /// [`super::RawParts::enabled_features`] takes, so that the two cannot disagree.
    ///
    /// # Safety
    /// `info` is valid as `vkCreateDevice` requires: its `pNext` chain holds live structs
    /// whose `sType` matches their type, and its extension names are live C strings.
    pub unsafe fn from_device_create_info(
        info: &vk::DeviceCreateInfo<'_>,
        api_version: u32,
    ) -> Self {
        let on = |b: vk::Bool32| b == vk::TRUE;
        let mut f = DeviceFeatures {
            api_1_3: api_version >= vk::API_VERSION_1_3,
            ..Self::default()
        };
        // SAFETY: the caller's contract: pEnabledFeatures is null or a live struct.
        let mut base = unsafe { info.p_enabled_features.as_ref() }
            .copied()
            .unwrap_or_default();
        let (mut accel, mut query) = (false, false);
        let mut next = info.p_next.cast::<vk::BaseInStructure<'_>>();
        // SAFETY: the caller's contract: a live struct of this sType, live names.
        while let Some(s) = unsafe { next.as_ref() } {
            let at = next.cast::<u8>();
            match s.s_type {
                vk::StructureType::PHYSICAL_DEVICE_FEATURES_2 => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    base = unsafe { &*at.cast::<vk::PhysicalDeviceFeatures2<'_>>() }.features;
                }
                vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_1_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDeviceVulkan11Features<'_>>() };
                    f.storage_buffer_16bit |= on(v.storage_buffer16_bit_access);
                }
                vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_2_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDeviceVulkan12Features<'_>>() };
                    f.storage_buffer_8bit |= on(v.storage_buffer8_bit_access);
                    f.shader_int8 |= on(v.shader_int8);
                    f.shader_float16 |= on(v.shader_float16);
                    f.shader_buffer_int64_atomics |= on(v.shader_buffer_int64_atomics);
                    f.host_query_reset |= on(v.host_query_reset);
                    f.buffer_device_address |= on(v.buffer_device_address);
                }
                vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_3_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDeviceVulkan13Features<'_>>() };
                    f.subgroup_size_control |= on(v.subgroup_size_control);
                    f.compute_full_subgroups |= on(v.compute_full_subgroups);
                }
                vk::StructureType::PHYSICAL_DEVICE_8BIT_STORAGE_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDevice8BitStorageFeatures<'_>>() };
                    f.storage_buffer_8bit |= on(v.storage_buffer8_bit_access);
                }
                vk::StructureType::PHYSICAL_DEVICE_16BIT_STORAGE_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDevice16BitStorageFeatures<'_>>() };
                    f.storage_buffer_16bit |= on(v.storage_buffer16_bit_access);
                }
                vk::StructureType::PHYSICAL_DEVICE_SHADER_FLOAT16_INT8_FEATURES => {
                    let v =
                        // SAFETY: the caller's contract: a live struct of this sType, live names.
                        unsafe { &*at.cast::<vk::PhysicalDeviceShaderFloat16Int8Features<'_>>() };
                    f.shader_float16 |= on(v.shader_float16);
                    f.shader_int8 |= on(v.shader_int8);
                }
                vk::StructureType::PHYSICAL_DEVICE_SHADER_ATOMIC_INT64_FEATURES => {
                    let v =
                        // SAFETY: the caller's contract: a live struct of this sType, live names.
                        unsafe { &*at.cast::<vk::PhysicalDeviceShaderAtomicInt64Features<'_>>() };
                    f.shader_buffer_int64_atomics |= on(v.shader_buffer_int64_atomics);
                }
                vk::StructureType::PHYSICAL_DEVICE_BUFFER_DEVICE_ADDRESS_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v =
                        unsafe { &*at.cast::<vk::PhysicalDeviceBufferDeviceAddressFeatures<'_>>() };
                    f.buffer_device_address |= on(v.buffer_device_address);
                }
                vk::StructureType::PHYSICAL_DEVICE_HOST_QUERY_RESET_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDeviceHostQueryResetFeatures<'_>>() };
                    f.host_query_reset |= on(v.host_query_reset);
                }
                vk::StructureType::PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_FEATURES => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v =
                        unsafe { &*at.cast::<vk::PhysicalDeviceSubgroupSizeControlFeatures<'_>>() };
                    f.subgroup_size_control |= on(v.subgroup_size_control);
                    f.compute_full_subgroups |= on(v.compute_full_subgroups);
                }
                vk::StructureType::PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe {
                        &*at.cast::<vk::PhysicalDeviceAccelerationStructureFeaturesKHR<'_>>()
                    };
                    accel = on(v.acceleration_structure);
                }
                vk::StructureType::PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR => {
                    // SAFETY: the caller's contract: a live struct of this sType, live names.
                    let v = unsafe { &*at.cast::<vk::PhysicalDeviceRayQueryFeaturesKHR<'_>>() };
                    query = on(v.ray_query);
                }
                _ => {}
            }
            next = s.p_next;
        }
        f.shader_int16 = on(base.shader_int16);
        f.shader_int64 = on(base.shader_int64);
        f.shader_float64 = on(base.shader_float64);
        f.pipeline_statistics_query = on(base.pipeline_statistics_query);
        let names: &[*const std::ffi::c_char] = match info.enabled_extension_count {
            0 => &[],
            // SAFETY: the caller's contract: a live struct of this sType, live names.
            n => unsafe { std::slice::from_raw_parts(info.pp_enabled_extension_names, n as usize) },
        };
        let enabled = |name: &std::ffi::CStr| {
            names
                .iter()
                // SAFETY: the caller's contract: a live struct of this sType, live names.
                .any(|&p| !p.is_null() && unsafe { std::ffi::CStr::from_ptr(p) } == name)
        };
        f.ray_query = accel
            && query
            && f.buffer_device_address
            && RAY_QUERY_EXTENSIONS.iter().all(|&n| enabled(n));
        f.calibrated_timestamps = CalibratedTimestamps::among(enabled);
        f.push_descriptor = enabled(ash::khr::push_descriptor::NAME);
        f
    }
}

/// The feature structs and extensions that enable a [`DeviceFeatures`] set on a device, as
/// vkrt enables them on a device it creates: for a renderer that creates its own, chain
/// `v11` and `v12` (and `size_control`, `acceleration_structure` and `ray_query` where
/// present) into its `VkDeviceCreateInfo` with `base` as `pEnabledFeatures` and
/// `extensions` among its extensions — or set the same flags in the structs it already
/// chains. [`DeviceFeatures::from_device_create_info`] of the result gives the set back.
#[derive(Clone, Debug, Default)]
pub struct DeviceFeatureRequest {
    /// `VkPhysicalDeviceFeatures`: `shaderInt16`, `shaderInt64`, `shaderFloat64`,
    /// `pipelineStatisticsQuery`.
    pub base: vk::PhysicalDeviceFeatures,
    /// `storageBuffer16BitAccess`.
    pub v11: vk::PhysicalDeviceVulkan11Features<'static>,
    /// 8-bit storage and arithmetic, 16-bit floats, 64-bit atomics, host query reset,
    /// `bufferDeviceAddress`.
    pub v12: vk::PhysicalDeviceVulkan12Features<'static>,
    /// Subgroup size control (core in Vulkan 1.3; `VK_EXT_subgroup_size_control` before).
    pub size_control: Option<vk::PhysicalDeviceSubgroupSizeControlFeatures<'static>>,
    /// The driver's acceleration structures (with `ray_query`).
    pub acceleration_structure: Option<vk::PhysicalDeviceAccelerationStructureFeaturesKHR<'static>>,
    /// The driver's ray query.
    pub ray_query: Option<vk::PhysicalDeviceRayQueryFeaturesKHR<'static>>,
    /// The device extensions these need.
    pub extensions: Vec<&'static std::ffi::CStr>,
}

impl DeviceFeatures {
    /// What `pd` supports of the features vkrt uses (what a context vkrt creates enables).
    pub fn supported(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Self {
        supported_features(instance, pd)
    }

    /// The structs and extensions that enable this set ([`DeviceFeatureRequest`]).
    pub fn request(&self) -> DeviceFeatureRequest {
        let mut r = DeviceFeatureRequest {
            base: vk::PhysicalDeviceFeatures::default()
                .shader_int64(self.shader_int64)
                .shader_float64(self.shader_float64)
                .shader_int16(self.shader_int16)
                .pipeline_statistics_query(self.pipeline_statistics_query),
            v11: vk::PhysicalDeviceVulkan11Features::default()
                .storage_buffer16_bit_access(self.storage_buffer_16bit),
            v12: vk::PhysicalDeviceVulkan12Features::default()
                .storage_buffer8_bit_access(self.storage_buffer_8bit)
                .shader_int8(self.shader_int8)
                .shader_buffer_int64_atomics(self.shader_buffer_int64_atomics)
                .shader_float16(self.shader_float16)
                .host_query_reset(self.host_query_reset)
                .buffer_device_address(self.buffer_device_address || self.ray_query),
            ..DeviceFeatureRequest::default()
        };
        if self.subgroup_size_control {
            if !self.api_1_3 {
                r.extensions.push(ash::ext::subgroup_size_control::NAME);
            }
            r.size_control = Some(
                vk::PhysicalDeviceSubgroupSizeControlFeatures::default()
                    .subgroup_size_control(true)
                    .compute_full_subgroups(self.compute_full_subgroups),
            );
        }
        if self.ray_query {
            r.extensions.extend(RAY_QUERY_EXTENSIONS);
            r.acceleration_structure = Some(
                vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
                    .acceleration_structure(true),
            );
            r.ray_query = Some(vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true));
        }
        r.extensions
            .extend(self.calibrated_timestamps.map(CalibratedTimestamps::name));
        if self.push_descriptor {
            r.extensions.push(ash::khr::push_descriptor::NAME);
        }
        r
    }
}

/// The device extensions [`DeviceFeatures::ray_query`] enables.
pub(crate) const RAY_QUERY_EXTENSIONS: [&std::ffi::CStr; 3] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::deferred_host_operations::NAME,
    ash::khr::ray_query::NAME,
];

/// Device facts. The JSON of `vkrt info --json` is this struct.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceInfo {
    /// The device name the driver reports (`deviceName`).
    pub device: String,
    /// The driver's name and info string (e.g. `llvmpipe Mesa 25.0.7 (LLVM 15.0.6)`).
    pub driver: String,
    /// The Vulkan version the device speaks, as `major.minor.patch`.
    pub api_version: String,
    /// `discrete`, `integrated`, `virtual`, `cpu` or `other`.
    pub device_type: String,
    /// `subgroupSize`: invocations per subgroup when a pipeline does not ask for a size.
    pub subgroup_size: u32,
    /// `minSubgroupSize` (Vulkan 1.3); `subgroup_size` on older devices.
    pub min_subgroup_size: u32,
    /// `maxSubgroupSize` (Vulkan 1.3); `subgroup_size` on older devices.
    pub max_subgroup_size: u32,
    /// The supported subgroup operation classes (`basic`, `vote`, `arithmetic`, …).
    pub subgroup_ops: Vec<&'static str>,
    /// Subgroup operations are supported in compute shaders (a requirement of vkrt).
    pub subgroup_in_compute: bool,
    /// `maxStorageBufferRange`: the most bytes one storage-buffer binding may cover.
    pub max_storage_buffer_range: u64,
    /// `minStorageBufferOffsetAlignment`: where a bound range of a buffer may start.
    pub min_storage_buffer_offset_alignment: u64,
    /// `minTexelBufferOffsetAlignment`: where a texel-buffer view may start.
    pub min_texel_buffer_offset_alignment: u64,
    /// `maxTexelBufferElements`: texels one texel-buffer view may hold.
    pub max_texel_buffer_elements: u32,
    /// `maxComputeSharedMemorySize`: bytes of shared memory one workgroup may use.
    pub max_shared_memory: u32,
    /// `maxComputeWorkGroupInvocations`: the most invocations in one workgroup.
    pub max_workgroup_invocations: u32,
    /// `maxComputeWorkGroupSize`: the largest workgroup size per axis.
    pub max_workgroup_size: [u32; 3],
    /// `maxComputeWorkGroupCount`: the most workgroups one dispatch may launch per axis.
    pub max_workgroup_count: [u32; 3],
    /// `maxPushConstantsSize`: bytes of push constants a pipeline may use.
    pub max_push_constants_size: u32,
    /// `timestampPeriod`: nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Timestamps work: `timestampComputeAndGraphics`, and (in a context) the queue family
    /// has timestamp bits. Without them the profiler's pass times are `None`.
    pub timestamps: bool,
    /// The driver's f32 division and square root round correctly (lavapipe's are the CPU's
    /// instructions). Vulkan allows 2.5 and 3 ulps, so elsewhere the exact walks check the
    /// driver's answer against an exact residual (`div_rn` in `vkrt/ray.glsl`).
    pub ieee_division: bool,
    /// Loop iterations an invocation may run in all before the driver silently ends its
    /// loops: llvmpipe's 65,535 (gallivm's `LP_MAX_TGSI_LOOP_ITERATIONS`, shared by every
    /// loop of the invocation); `None` where loops run to their end. `vkrt verify` measures it.
    pub loop_budget: Option<u32>,
    /// vkrt's walks read a structure faster through texel buffers than through storage
    /// buffers here, as measured (`vkrt bench trace --node-access both`): lavapipe before
    /// Mesa 25, where a storage load at a divergent offset is a loop over the lanes and a
    /// texel fetch the sampler's branch-free gather (Mesa 22.3: texel 1.47× faster, median
    /// of 450 walks and ray sets). Not on Mesa 25.0's lavapipe (storage 1.18× faster, the
    /// same way) nor on other drivers, which read storage buffers.
    pub texel_walks: bool,
    /// vkrt's BVHs are walked 4-wide by default here
    /// ([`Traversal::for_device`](crate::accel::walk::Traversal::for_device)), as measured
    /// (`vkrt bench trace`: SAH BVH, LBVH and PLOC; the bunny and a 100 K icosphere; primary,
    /// shadow and mirror rays): lavapipe from Mesa 25.1, the divergence-aware gallivm
    /// (Mesa 26.1.6: the 4-wide walk 1.03–1.47× the binary stack walk's rate in all 18
    /// cases). Not on Mesa 25.0's (0.84–1.26×, slower in 7 of 18), nor on older lavapipe
    /// (texel reads: 0.49–0.95×), nor on NVIDIA's H100 (0.67–0.81×): the binary stack walk
    /// stays there.
    pub wide_walks: bool,
    /// The chained scan keeps each lane's granules in rolled loops, reading them twice
    /// (`glsl/prims/scan_chained.comp`'s `ROLLED`), rather than in registers across its
    /// look-back: lavapipe before Mesa 25.1, as measured (`vkrt bench prims --only scan`,
    /// 2^24 elements, default shape: Mesa 25.0.7 u32 8.0–8.2 ms rolled against 13.0–14.1,
    /// flags 4.5–4.8 against 6.8–7.2, and the large tiles' kernel compiles in about 1 s
    /// instead of 25; Mesa 22.3 the same either way). Not on Mesa 26.1.6 (rolled 1.6×
    /// slower: 16.7–17.7 against 10.5–10.6 ms) nor on other drivers.
    pub rolled_scan_tiles: bool,
    /// Node visits + primitive tests a walk may spend per ray before it gives up and reports
    /// the ray as exhausted: 60,000 within a loop budget (the rest is the walk's other
    /// loops' headroom), 2^24 elsewhere (a guard against a corrupt structure, far above
    /// any real tree's walk). Specialization constant 22 of every walking kernel.
    pub max_traversal_steps: u32,
    /// The optional features enabled on the device (all that it supports, for a context
    /// vkrt creates; those the caller names, for an adopted device).
    pub features: DeviceFeatures,
    #[serde(skip)]
    pub(crate) api_version_raw: u32,
    #[serde(skip)]
    pub(crate) type_rank: u32,
    #[serde(skip)]
    pub(crate) subgroup_ops_raw: vk::SubgroupFeatureFlags,
    #[serde(skip)]
    pub(crate) pipeline_cache_uuid: [u8; 16],
}

const SUBGROUP_OPS: [(vk::SubgroupFeatureFlags, &str); 8] = [
    (vk::SubgroupFeatureFlags::BASIC, "basic"),
    (vk::SubgroupFeatureFlags::VOTE, "vote"),
    (vk::SubgroupFeatureFlags::ARITHMETIC, "arithmetic"),
    (vk::SubgroupFeatureFlags::BALLOT, "ballot"),
    (vk::SubgroupFeatureFlags::SHUFFLE, "shuffle"),
    (
        vk::SubgroupFeatureFlags::SHUFFLE_RELATIVE,
        "shuffle_relative",
    ),
    (vk::SubgroupFeatureFlags::CLUSTERED, "clustered"),
    (vk::SubgroupFeatureFlags::QUAD, "quad"),
];

/// The subgroup operations every vkrt kernel may use.
const REQUIRED_OPS: [(vk::SubgroupFeatureFlags, &str); 5] = [
    (vk::SubgroupFeatureFlags::BASIC, "basic"),
    (vk::SubgroupFeatureFlags::ARITHMETIC, "arithmetic"),
    (vk::SubgroupFeatureFlags::BALLOT, "ballot"),
    (vk::SubgroupFeatureFlags::SHUFFLE, "shuffle"),
    (
        vk::SubgroupFeatureFlags::SHUFFLE_RELATIVE,
        "shuffle_relative",
    ),
];

pub(crate) fn query(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    features: DeviceFeatures,
) -> DeviceInfo {
    let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut size_control = vk::PhysicalDeviceSubgroupSizeControlProperties::default();
    // SAFETY: a plain query of a valid physical device; the base properties are read first
    // so the 1.3 struct is chained only where the device knows it.
    let base = unsafe { instance.get_physical_device_properties(pd) };
    let has_13 = base.api_version >= vk::API_VERSION_1_3;
    let mut props2 = vk::PhysicalDeviceProperties2::default()
        .push_next(&mut subgroup)
        .push_next(&mut driver);
    if has_13 {
        props2 = props2.push_next(&mut size_control);
    }
    // SAFETY: as above; every chained struct lives across the call.
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    let p = props2.properties;
    let limits = p.limits;
    let v = p.api_version;
    let name = p
        .device_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let driver_name = driver
        .driver_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let driver_info = driver
        .driver_info_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (device_type, type_rank) = match p.device_type {
        vk::PhysicalDeviceType::DISCRETE_GPU => ("discrete", 0),
        vk::PhysicalDeviceType::INTEGRATED_GPU => ("integrated", 1),
        vk::PhysicalDeviceType::VIRTUAL_GPU => ("virtual", 2),
        vk::PhysicalDeviceType::CPU => ("cpu", 3),
        _ => ("other", 4),
    };
    let (min_sg, max_sg) = if has_13 {
        (
            size_control.min_subgroup_size,
            size_control.max_subgroup_size,
        )
    } else {
        (subgroup.subgroup_size, subgroup.subgroup_size)
    };
    // lavapipe's Mesa version (`None` inside: one it cannot read).
    let lavapipe =
        (driver.driver_id == vk::DriverId::MESA_LLVMPIPE).then(|| mesa_version(&driver_info));
    let loop_budget = lavapipe
        .is_some_and(|v| v.is_none_or(|v| v < (25, 0)))
        .then_some(LLVMPIPE_LOOP_BUDGET);
    let texel_walks = lavapipe.is_some_and(|v| v.is_some_and(|v| v < (25, 0)));
    let wide_walks = lavapipe.is_some_and(|v| v.is_some_and(|v| v >= (25, 1)));
    let rolled_scan_tiles = lavapipe.is_some_and(|v| v.is_none_or(|v| v < (25, 1)));
    DeviceInfo {
        device: name,
        driver: format!("{driver_name} {driver_info}").trim().to_string(),
        api_version: format!(
            "{}.{}.{}",
            vk::api_version_major(v),
            vk::api_version_minor(v),
            vk::api_version_patch(v)
        ),
        device_type: device_type.into(),
        subgroup_size: subgroup.subgroup_size,
        min_subgroup_size: min_sg,
        max_subgroup_size: max_sg,
        subgroup_ops: SUBGROUP_OPS
            .iter()
            .filter(|(f, _)| subgroup.supported_operations.contains(*f))
            .map(|(_, n)| *n)
            .collect(),
        subgroup_in_compute: subgroup
            .supported_stages
            .contains(vk::ShaderStageFlags::COMPUTE),
        max_storage_buffer_range: u64::from(limits.max_storage_buffer_range),
        min_storage_buffer_offset_alignment: limits.min_storage_buffer_offset_alignment,
        min_texel_buffer_offset_alignment: limits.min_texel_buffer_offset_alignment,
        max_texel_buffer_elements: limits.max_texel_buffer_elements,
        max_shared_memory: limits.max_compute_shared_memory_size,
        max_workgroup_invocations: limits.max_compute_work_group_invocations,
        max_workgroup_size: limits.max_compute_work_group_size,
        max_workgroup_count: limits.max_compute_work_group_count,
        max_push_constants_size: limits.max_push_constants_size,
        timestamp_period_ns: limits.timestamp_period,
        timestamps: limits.timestamp_compute_and_graphics == vk::TRUE,
        ieee_division: driver.driver_id == vk::DriverId::MESA_LLVMPIPE,
        loop_budget,
        texel_walks,
        wide_walks,
        rolled_scan_tiles,
        max_traversal_steps: traversal_steps_within(loop_budget),
        features,
        api_version_raw: v,
        type_rank,
        subgroup_ops_raw: subgroup.supported_operations,
        pipeline_cache_uuid: p.pipeline_cache_uuid,
    }
}

/// Loop iterations a llvmpipe invocation runs in all its loops together before the rest are
/// skipped (gallivm's `LP_MAX_TGSI_LOOP_ITERATIONS`). Measured: Mesa 22.3 has it, 25.0 runs
/// loops to their end. Versions between (or unknown) are taken to have it: a lower step cap
/// costs nothing on real trees, a missing one would make silent misses.
pub const LLVMPIPE_LOOP_BUDGET: u32 = 65_535;

/// `(major, minor)` of "Mesa X.Y…" in a driver's info string ([`DeviceInfo::driver`] holds
/// one), to tell lavapipe versions and their known bugs apart.
pub fn mesa_version(driver_info: &str) -> Option<(u32, u32)> {
    let rest = &driver_info[driver_info.find("Mesa ")? + 5..];
    let mut parts = rest.split(|c: char| !c.is_ascii_digit());
    let major = parts.next()?.parse().ok()?;
    let minor = parts.next()?.parse().ok()?;
    Some((major, minor))
}

/// The walks' step cap on a device with `loop_budget` ([`DeviceInfo::max_traversal_steps`]).
pub fn traversal_steps_within(loop_budget: Option<u32>) -> u32 {
    match loop_budget {
        Some(budget) => budget.saturating_sub(5_535).max(1),
        None => 1 << 24,
    }
}

/// What this device supports of the features vkrt wants.
pub(crate) fn supported_features(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
) -> DeviceFeatures {
    // SAFETY: plain queries of a valid physical device.
    let api = unsafe { instance.get_physical_device_properties(pd) }.api_version;
    let mut f11 = vk::PhysicalDeviceVulkan11Features::default();
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut size_control = vk::PhysicalDeviceSubgroupSizeControlFeatures::default();
    let mut accel = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
    let mut query = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
    // SAFETY: as above.
    let extensions =
        unsafe { instance.enumerate_device_extension_properties(pd) }.unwrap_or_default();
    let has_ext = |name: &std::ffi::CStr| {
        extensions
            .iter()
            .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name))
    };
    let has_size_control_ext = has_ext(ash::ext::subgroup_size_control::NAME);
    let has_ray_query_exts = RAY_QUERY_EXTENSIONS.iter().all(|&n| has_ext(n));
    let api_1_3 = api >= vk::API_VERSION_1_3;
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut f11)
        .push_next(&mut f12);
    if api_1_3 || has_size_control_ext {
        f2 = f2.push_next(&mut size_control);
    }
    if has_ray_query_exts {
        f2 = f2.push_next(&mut accel).push_next(&mut query);
    }
    // SAFETY: every chained struct lives across the call.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let base = f2.features;
    DeviceFeatures {
        storage_buffer_8bit: f12.storage_buffer8_bit_access == vk::TRUE,
        storage_buffer_16bit: f11.storage_buffer16_bit_access == vk::TRUE,
        shader_int8: f12.shader_int8 == vk::TRUE,
        shader_int16: base.shader_int16 == vk::TRUE,
        shader_int64: base.shader_int64 == vk::TRUE,
        shader_buffer_int64_atomics: f12.shader_buffer_int64_atomics == vk::TRUE,
        shader_float64: base.shader_float64 == vk::TRUE,
        shader_float16: f12.shader_float16 == vk::TRUE,
        host_query_reset: f12.host_query_reset == vk::TRUE,
        pipeline_statistics_query: base.pipeline_statistics_query == vk::TRUE,
        subgroup_size_control: size_control.subgroup_size_control == vk::TRUE,
        compute_full_subgroups: size_control.compute_full_subgroups == vk::TRUE,
        api_1_3,
        buffer_device_address: f12.buffer_device_address == vk::TRUE,
        ray_query: has_ray_query_exts
            && accel.acceleration_structure == vk::TRUE
            && query.ray_query == vk::TRUE
            && f12.buffer_device_address == vk::TRUE,
        calibrated_timestamps: CalibratedTimestamps::among(has_ext),
        push_descriptor: has_ext(ash::khr::push_descriptor::NAME),
    }
}

/// Fails with an error naming the first missing capability.
pub(crate) fn check_requirements(info: &DeviceInfo) -> Result<()> {
    let missing = |what: String| GpuError::MissingCapability {
        device: info.device.clone(),
        what,
    };
    if info.api_version_raw < vk::API_VERSION_1_2 {
        return Err(missing(format!(
            "Vulkan 1.2 (device speaks {})",
            info.api_version
        )));
    }
    if !info.subgroup_in_compute {
        return Err(missing("subgroup operations in compute shaders".into()));
    }
    for (flag, name) in REQUIRED_OPS {
        if !info.subgroup_ops_raw.contains(flag) {
            return Err(missing(format!("subgroup operation `{name}` in compute")));
        }
    }
    if !info.subgroup_size.is_power_of_two() || info.subgroup_size < 4 {
        return Err(missing(format!(
            "a power-of-two subgroup size of at least 4 (device reports {})",
            info.subgroup_size
        )));
    }
    Ok(())
}

pub(crate) fn compute_queue_family(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
) -> Option<u32> {
    // SAFETY: a plain query of a valid physical device.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    // Prefer a compute family without graphics (async compute), else any with compute.
    let with = |f: &vk::QueueFamilyProperties| f.queue_flags.contains(vk::QueueFlags::COMPUTE);
    families
        .iter()
        .position(|f| with(f) && !f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
        .or_else(|| families.iter().position(with))
        .map(|i| i as u32)
}

pub(crate) fn timestamp_bits(instance: &ash::Instance, pd: vk::PhysicalDevice, family: u32) -> u32 {
    // SAFETY: a plain query of a valid physical device.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    families
        .get(family as usize)
        .map_or(0, |f| f.timestamp_valid_bits)
}

/// What a host enables on the device it hands to [`super::Context::from_raw`], and why.
///
/// Required: a Vulkan 1.2 device whose compute queue runs subgroup operations
/// ([`DeviceRequirements::subgroup_operations`]) with a power-of-two subgroup size of at
/// least 4 — these are properties to check, not features to enable. Everything else is
/// optional and says what it buys; tell vkrt what was enabled in
/// [`super::RawParts::enabled_features`].
#[derive(Clone, Debug)]
pub struct DeviceRequirements {
    /// The lowest Vulkan version, encoded as by `vk::make_api_version` (1.2).
    pub api_version: u32,
    /// The subgroup operations kernels use in compute shaders.
    pub subgroup_operations: vk::SubgroupFeatureFlags,
    /// Optional features, each with what it buys.
    pub optional_features: Vec<(&'static str, &'static str)>,
    /// The extensions of the driver's structure (`AccelKind::Driver` and the ray-query
    /// branch of `vkrt/ray_query.glsl`): enable them, with `accelerationStructure`,
    /// `rayQuery` and `bufferDeviceAddress`, to set `DeviceFeatures::ray_query`.
    pub ray_query_extensions: Vec<&'static std::ffi::CStr>,
}

/// The device requirements of vkrt ([`DeviceRequirements`]).
pub fn device_requirements() -> DeviceRequirements {
    DeviceRequirements {
        api_version: vk::API_VERSION_1_2,
        subgroup_operations: REQUIRED_OPS
            .iter()
            .fold(vk::SubgroupFeatureFlags::empty(), |a, (f, _)| a | *f),
        optional_features: vec![
            (
                "storageBuffer8BitAccess",
                "the GPU kd-tree builder (its 1-byte event flags); without it, an error",
            ),
            (
                "shaderInt64",
                "64-bit node loads of the exact walk, 64-bit Morton codes; with \
                 bufferDeviceAddress, two levels and `VKRT_DEVICE_ADDRESS` shaders (their \
                 SPIR-V declares Int64)",
            ),
            (
                "shaderFloat64",
                "the watertight test's exact fallback (`VKRT_EXACT`, with shaderInt64)",
            ),
            (
                "shaderBufferInt64Atomics",
                "the single-pass chained scan (a two-pass scan otherwise)",
            ),
            (
                "bufferDeviceAddress",
                "two levels (instances of bottom levels under a top level), geometry read at \
                 device addresses, `VKRT_DEVICE_ADDRESS` shaders; the driver's structure \
                 needs it too",
            ),
        ],
        ray_query_extensions: RAY_QUERY_EXTENSIONS.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::{
        mesa_version, traversal_steps_within, CalibratedTimestamps, DeviceFeatures,
        LLVMPIPE_LOOP_BUDGET,
    };
    use ash::vk;

    #[test]
    fn features_are_read_from_the_renderers_create_info() {
        // Base features through pEnabledFeatures, 1.2 features, a promoted extension's own
        // struct, and the driver's ray query without one of its extensions.
        let base = vk::PhysicalDeviceFeatures::default()
            .shader_int64(true)
            .shader_float64(true);
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .storage_buffer8_bit_access(true)
            .buffer_device_address(true)
            .host_query_reset(true);
        let mut atomics = vk::PhysicalDeviceShaderAtomicInt64Features::default()
            .shader_buffer_int64_atomics(true);
        let mut accel = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
            .acceleration_structure(true);
        let mut query = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
        let two = [
            ash::khr::acceleration_structure::NAME.as_ptr(),
            ash::khr::ray_query::NAME.as_ptr(),
        ];
        let info = vk::DeviceCreateInfo::default()
            .enabled_features(&base)
            .enabled_extension_names(&two)
            .push_next(&mut f12)
            .push_next(&mut atomics)
            .push_next(&mut accel)
            .push_next(&mut query);
        // SAFETY: every struct and name lives across the call.
        let f = unsafe { DeviceFeatures::from_device_create_info(&info, vk::API_VERSION_1_2) };
        let want = DeviceFeatures {
            storage_buffer_8bit: true,
            shader_int64: true,
            shader_float64: true,
            shader_buffer_int64_atomics: true,
            host_query_reset: true,
            buffer_device_address: true,
            ..DeviceFeatures::default()
        };
        assert_eq!(f, want, "ray query needs all three extensions");
        let three = [
            ash::khr::acceleration_structure::NAME.as_ptr(),
            ash::khr::deferred_host_operations::NAME.as_ptr(),
            ash::khr::ray_query::NAME.as_ptr(),
        ];
        let info = info.enabled_extension_names(&three);
        // SAFETY: as above.
        let f = unsafe { DeviceFeatures::from_device_create_info(&info, vk::API_VERSION_1_3) };
        assert_eq!(
            f,
            DeviceFeatures {
                ray_query: true,
                api_1_3: true,
                ..want
            }
        );
        // A VkPhysicalDeviceFeatures2 in the chain instead of pEnabledFeatures.
        let mut f2 = vk::PhysicalDeviceFeatures2::default().features(base.shader_int16(true));
        let info = vk::DeviceCreateInfo::default().push_next(&mut f2);
        // SAFETY: as above.
        let f = unsafe { DeviceFeatures::from_device_create_info(&info, vk::API_VERSION_1_2) };
        assert!(f.shader_int16 && f.shader_int64 && !f.buffer_device_address);
    }

    #[test]
    fn a_request_enables_exactly_its_features() {
        let all = DeviceFeatures {
            storage_buffer_8bit: true,
            storage_buffer_16bit: true,
            shader_int8: true,
            shader_int16: true,
            shader_int64: true,
            shader_buffer_int64_atomics: true,
            shader_float64: true,
            shader_float16: true,
            host_query_reset: true,
            pipeline_statistics_query: true,
            subgroup_size_control: true,
            compute_full_subgroups: true,
            api_1_3: false,
            buffer_device_address: true,
            ray_query: true,
            calibrated_timestamps: Some(CalibratedTimestamps::Khr),
            push_descriptor: true,
        };
        let some = DeviceFeatures {
            storage_buffer_8bit: true,
            shader_int64: true,
            api_1_3: true,
            calibrated_timestamps: Some(CalibratedTimestamps::Ext),
            ..DeviceFeatures::default()
        };
        for (want, api) in [(all, vk::API_VERSION_1_2), (some, vk::API_VERSION_1_3)] {
            let mut r = want.request();
            let names: Vec<_> = r.extensions.iter().map(|n| n.as_ptr()).collect();
            let mut info = vk::DeviceCreateInfo::default()
                .enabled_features(&r.base)
                .enabled_extension_names(&names)
                .push_next(&mut r.v11)
                .push_next(&mut r.v12);
            if let Some(s) = r.size_control.as_mut() {
                info = info.push_next(s);
            }
            if let (Some(a), Some(q)) = (r.acceleration_structure.as_mut(), r.ray_query.as_mut()) {
                info = info.push_next(a).push_next(q);
            }
            // SAFETY: every struct and name lives across the call.
            let got = unsafe { DeviceFeatures::from_device_create_info(&info, api) };
            assert_eq!(got, want);
        }
    }

    #[test]
    fn mesa_versions_parse_from_driver_info() {
        assert_eq!(
            mesa_version("Mesa 25.0.7-2~bpo12+1 (LLVM 15.0.6)"),
            Some((25, 0))
        );
        assert_eq!(mesa_version("Mesa 22.3.6 (LLVM 15.0.6)"), Some((22, 3)));
        assert_eq!(mesa_version("580.159.04"), None);
        assert_eq!(mesa_version("Mesa devel"), None);
    }

    #[test]
    fn the_step_cap_stays_inside_the_loop_budget() {
        let cap = traversal_steps_within(Some(LLVMPIPE_LOOP_BUDGET));
        assert_eq!(cap, 60_000);
        assert!(traversal_steps_within(None) > cap);
        assert_eq!(traversal_steps_within(Some(10)), 1);
    }
}
