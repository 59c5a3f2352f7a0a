//! The keys of a `[[meshes]]` entry that mirror the driver's instance record
//! (`VkAccelerationStructureInstanceKHR`) and its geometry's opaque flag: `mask`,
//! `custom_index`, `sbt_offset`, `flags` and `opaque`. `vkrt shader-check` places each
//! entry's instance with them; every other command ignores them.

#[cfg(feature = "scene-files")]
use super::error::{Origin, SceneError};

/// Largest custom index and shader-binding-table offset (24 bits each in the record).
pub const MAX_INSTANCE_FIELD: u32 = (1 << 24) - 1;

/// The names of `flags` entries and their bits (`VkGeometryInstanceFlagBitsKHR`).
pub const INSTANCE_FLAG_NAMES: [(&str, u8); 4] = [
    ("cull-disable", 0x1),
    ("flip-facing", 0x2),
    ("force-opaque", 0x4),
    ("force-no-opaque", 0x8),
];

/// One mesh entry's instance keys, as written or their defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InstanceKeys {
    /// The 8-bit visibility mask (default 255: seen by every ray).
    pub mask: u8,
    /// The custom index (24 bits); `None`: the instance's id.
    pub custom_index: Option<u32>,
    /// The shader-binding-table record offset (24 bits, default 0).
    pub sbt_offset: u32,
    /// `VkGeometryInstanceFlagBitsKHR` bits (default none).
    pub flags: u8,
    /// The geometry's opaque flag (default true).
    pub opaque: bool,
}

impl Default for InstanceKeys {
    fn default() -> Self {
        Self {
            mask: 0xff,
            custom_index: None,
            sbt_offset: 0,
            flags: 0,
            opaque: true,
        }
    }
}

impl InstanceKeys {
    /// The keys of an entry (`None`: absent), checked; `entry` is its key path
    /// (`meshes[2]`), which errors name with the key.
    #[cfg(feature = "scene-files")]
    pub(crate) fn from_def(
        entry: &str,
        mask: Option<i64>,
        custom_index: Option<i64>,
        sbt_offset: Option<i64>,
        flags: Option<&[String]>,
        opaque: Option<bool>,
    ) -> Result<Self, SceneError> {
        let ranged = |name: &str, v: Option<i64>, max: u32| -> Result<Option<u32>, SceneError> {
            match v {
                None => Ok(None),
                Some(v) if (0..=i64::from(max)).contains(&v) => Ok(Some(v as u32)),
                Some(v) => Err(SceneError::out_of_range(
                    Origin::key(format!("{entry}.{name}")),
                    v,
                    format!("must be 0..={max}"),
                )),
            }
        };
        let mut bits = 0u8;
        for (i, name) in flags.unwrap_or_default().iter().enumerate() {
            let Some(&(_, bit)) = INSTANCE_FLAG_NAMES.iter().find(|(n, _)| n == name) else {
                let known: Vec<&str> = INSTANCE_FLAG_NAMES.iter().map(|(n, _)| *n).collect();
                return Err(SceneError::UnknownName {
                    origin: Origin::key(format!("{entry}.flags[{i}]")),
                    kind: "instance flag",
                    name: name.clone(),
                    hint: format!("; known: {}", known.join(", ")).into(),
                });
            };
            bits |= bit;
        }
        Ok(Self {
            mask: ranged("mask", mask, 0xff)?.map_or(0xff, |m| m as u8),
            custom_index: ranged("custom_index", custom_index, MAX_INSTANCE_FIELD)?,
            sbt_offset: ranged("sbt_offset", sbt_offset, MAX_INSTANCE_FIELD)?.unwrap_or(0),
            flags: bits,
            opaque: opaque.unwrap_or(true),
        })
    }

    /// The names of the set flags, in the order of their bits.
    pub fn flag_names(&self) -> Vec<String> {
        INSTANCE_FLAG_NAMES
            .iter()
            .filter(|(_, bit)| self.flags & bit != 0)
            .map(|(n, _)| (*n).to_owned())
            .collect()
    }
}
