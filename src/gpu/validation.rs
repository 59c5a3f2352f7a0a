//! The Khronos validation layer, with synchronization validation, and the debug messenger
//! that collects what it says.
//!
//! lavapipe executes commands in order and hides missing barriers; the layer does not. Tests
//! create their context with [`Validation::FromEnv`] and fail on any collected message.

use std::ffi::{c_void, CStr};
use std::sync::Mutex;

use ash::vk;

pub(crate) const LAYER_NAME: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Whether to enable the validation layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Validation {
    /// Off.
    #[default]
    Off,
    /// On, with synchronization validation; an error if the layer is not installed.
    On,
    /// On when the layer is installed and `VKRT_VALIDATION` is not `0` (the test default).
    FromEnv,
}

impl Validation {
    /// Resolves the choice against what is installed. `Err` names why `On` cannot be honoured.
    pub(crate) fn resolve(self, layer_installed: bool) -> Result<bool, String> {
        match self {
            Validation::Off => Ok(false),
            Validation::On if layer_installed => Ok(true),
            Validation::On => Err(format!(
                "{} is not installed (Debian: vulkan-validationlayers)",
                LAYER_NAME.to_string_lossy()
            )),
            Validation::FromEnv => {
                let disabled = std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0");
                Ok(layer_installed && !disabled)
            }
        }
    }
}

/// One message from the validation layer (or the loader).
#[derive(Clone, Debug)]
pub struct ValidationMessage {
    /// `"error"` or `"warning"` (the only severities the messenger asks for).
    pub severity: &'static str,
    /// The message ID name (e.g. `SYNC-HAZARD-READ-AFTER-WRITE`); empty if none was given.
    pub id: String,
    /// The message text.
    pub text: String,
}

impl std::fmt::Display for ValidationMessage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "[{}] {}: {}", self.severity, self.id, self.text)
    }
}

/// Where the messenger callback puts messages; boxed so its address is stable for the
/// lifetime of the messenger.
#[derive(Default)]
pub(crate) struct MessageSink {
    pub(crate) messages: Mutex<Vec<ValidationMessage>>,
}

pub(crate) fn messenger_info(sink: &MessageSink) -> vk::DebugUtilsMessengerCreateInfoEXT<'_> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(callback))
        .user_data(sink as *const MessageSink as *mut c_void)
}

/// The validation features chained into the instance: synchronization validation; with
/// `VKRT_BOUNDS=1` instead GPU-assisted validation, which instruments every shader to check
/// each buffer access against its descriptor's range (and each device address against its
/// buffer). lavapipe's device memory is host memory, so an access past a binding corrupts
/// the host heap; on a GPU it corrupts a neighbouring buffer silently. The core checks are
/// off in that mode (the layer's advice: both together are very slow; the plain mode runs
/// them).
pub(crate) fn features() -> (
    Vec<vk::ValidationFeatureEnableEXT>,
    Vec<vk::ValidationFeatureDisableEXT>,
) {
    if bounds_checked() {
        (
            vec![vk::ValidationFeatureEnableEXT::GPU_ASSISTED],
            vec![
                vk::ValidationFeatureDisableEXT::CORE_CHECKS,
                vk::ValidationFeatureDisableEXT::THREAD_SAFETY,
            ],
        )
    } else {
        (
            vec![vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION],
            vec![],
        )
    }
}

/// Whether `VKRT_BOUNDS=1` asks for the shader bounds checks (with validation on).
pub(crate) fn bounds_checked() -> bool {
    std::env::var("VKRT_BOUNDS").is_ok_and(|v| v.trim() == "1")
}

unsafe extern "system" fn callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the loader passes a valid callback-data pointer for the duration of the call,
    // and `user_data` is the `MessageSink` that outlives the messenger (see Context::drop).
    let (data, sink) = unsafe { (&*data, &*(user_data as *const MessageSink)) };
    // SAFETY: the strings, when non-null, are NUL-terminated and valid during the call.
    let cstr = |p: *const std::ffi::c_char| unsafe {
        if p.is_null() {
            String::new()
        } else {
            CStr::from_ptr(p).to_string_lossy().into_owned()
        }
    };
    let error = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR);
    let text = cstr(data.p_message);
    // GPU-assisted validation turns on the features its instrumentation needs and says so.
    if !error && text.contains("Internal Warning: Forcing") {
        return vk::FALSE;
    }
    let message = ValidationMessage {
        severity: if error { "error" } else { "warning" },
        id: cstr(data.p_message_id_name),
        text,
    };
    // Through `log`, so the embedding application (or the CLI's -q/-v) decides what shows;
    // the sink keeps every message regardless.
    let level = if error {
        log::Level::Error
    } else {
        log::Level::Warn
    };
    log::log!(level, "validation: {}: {}", message.id, message.text);
    if let Ok(mut messages) = sink.messages.lock() {
        messages.push(message);
    }
    vk::FALSE
}
