//! What a TOML scene file says, as serde types. Every table has
//! `deny_unknown_fields`, so a misspelt key is an error with its span.
//! The writer serializes the same types (absent options are left out).

use std::fmt;

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

/// A number (all three components equal) or an array of three numbers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Vec3OrScalar(pub(super) [f32; 3]);

impl Serialize for Vec3OrScalar {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Vec3OrScalar {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Vec3OrScalar;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an array of 3 numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(Vec3OrScalar([v as f32; 3]))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(Vec3OrScalar([v as f32; 3]))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(Vec3OrScalar([v as f32; 3]))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut out = [0.0f32; 3];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq
                        .next_element()?
                        .ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                if seq.next_element::<de::IgnoredAny>()?.is_some() {
                    return Err(de::Error::invalid_length(4, &self));
                }
                Ok(Vec3OrScalar(out))
            }
        }
        d.deserialize_any(V)
    }
}

/// A TOML table read in document order (material ids follow the file, so
/// that a written scene reads back with the same ids).
#[derive(Debug)]
pub(super) struct Ordered<T>(pub(super) Vec<(String, T)>);

impl<T> Default for Ordered<T> {
    fn default() -> Self {
        Ordered(Vec::new())
    }
}

impl<T> Ordered<T> {
    pub(super) fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl<T: Serialize> Serialize for Ordered<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|(k, v)| (k, v)))
    }
}

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Ordered<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
            type Value = Ordered<T>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a table")
            }
            fn visit_map<A: de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = map.next_entry::<String, T>()? {
                    out.push((k, v));
                }
                Ok(Ordered(out))
            }
        }
        d.deserialize_map(V(std::marker::PhantomData))
    }
}

#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneDef {
    pub(super) ambient: Option<[f32; 3]>,
    pub(super) settings: Option<SettingsDef>,
    pub(super) camera: Option<CameraDef>,
    pub(super) animation: Option<AnimationDef>,
    #[serde(default, skip_serializing_if = "Ordered::is_empty")]
    pub(super) materials: Ordered<MaterialDef>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) lights: Vec<LightDef>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) spheres: Vec<SphereDef>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) meshes: Vec<MeshDef>,
}

#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SettingsDef {
    pub(super) width: Option<u32>,
    pub(super) height: Option<u32>,
    pub(super) spp: Option<u32>,
    pub(super) max_depth: Option<u32>,
    pub(super) background: Option<[f32; 3]>,
    pub(super) antialias: Option<bool>,
    pub(super) ao: Option<AoDef>,
}

#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AoDef {
    pub(super) enabled: Option<bool>,
    pub(super) radius: Option<f32>,
    pub(super) samples: Option<u32>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CameraDef {
    pub(super) position: [f32; 3],
    pub(super) look_at: [f32; 3],
    pub(super) up: Option<[f32; 3]>,
    pub(super) fov: Option<f32>,
    pub(super) aperture: Option<f32>,
    pub(super) focus_distance: Option<f32>,
    pub(super) shutter: Option<[f32; 2]>,
}

/// `[animation]`: `fps` and exactly one of `frames` or `end_time`.
#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AnimationDef {
    pub(super) fps: f32,
    pub(super) frames: Option<u32>,
    pub(super) end_time: Option<f32>,
}

#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MaterialDef {
    pub(super) diffuse: Option<[f32; 3]>,
    pub(super) specular: Option<Vec3OrScalar>,
    pub(super) shininess: Option<f32>,
    pub(super) mirror: Option<Vec3OrScalar>,
    pub(super) roughness: Option<f32>,
    pub(super) transmission: Option<f32>,
    pub(super) ior: Option<f32>,
    pub(super) fresnel: Option<bool>,
    pub(super) emission: Option<[f32; 3]>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum LightKind {
    Point,
    Sphere,
    Quad,
    Directional,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LightDef {
    #[serde(rename = "type")]
    pub(super) kind: LightKind,
    pub(super) position: Option<[f32; 3]>,
    pub(super) center: Option<[f32; 3]>,
    pub(super) radius: Option<f32>,
    pub(super) corner: Option<[f32; 3]>,
    pub(super) edge_u: Option<[f32; 3]>,
    pub(super) edge_v: Option<[f32; 3]>,
    pub(super) direction: Option<[f32; 3]>,
    pub(super) color: Option<[f32; 3]>,
    pub(super) intensity: Option<f32>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct OrbitDef {
    pub(super) center: Option<[f32; 3]>,
    pub(super) axis: Option<[f32; 3]>,
    pub(super) degrees_per_second: f32,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SphereDef {
    pub(super) center: [f32; 3],
    pub(super) radius: f32,
    pub(super) material: Option<String>,
    pub(super) velocity: Option<[f32; 3]>,
    pub(super) orbit: Option<OrbitDef>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum GenKind {
    Icosphere,
    GeodesicSphere,
    RandomSoup,
    IntegerGrid,
    SphereFlake,
}

#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MeshDef {
    pub(super) name: Option<String>,
    pub(super) path: Option<String>,
    pub(super) positions: Option<Vec<[f32; 3]>>,
    pub(super) normals: Option<Vec<[f32; 3]>>,
    pub(super) indices: Option<Vec<[u32; 3]>>,
    pub(super) generate: Option<GenKind>,
    pub(super) subdivisions: Option<u32>,
    pub(super) frequency: Option<u32>,
    pub(super) min_triangles: Option<u64>,
    pub(super) count: Option<u32>,
    pub(super) seed: Option<u64>,
    pub(super) nx: Option<u32>,
    pub(super) ny: Option<u32>,
    pub(super) depth: Option<u32>,
    pub(super) material: Option<String>,
    pub(super) triangle_materials: Option<Vec<String>>,
    pub(super) translate: Option<[f32; 3]>,
    pub(super) rotate: Option<[f32; 3]>,
    pub(super) scale: Option<Vec3OrScalar>,
    pub(super) velocity: Option<[f32; 3]>,
    pub(super) orbit: Option<OrbitDef>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) keyframes: Vec<KeyframeDef>,
    /// The entry to use instead when `path` does not exist.
    pub(super) fallback: Option<Box<MeshDef>>,
    /// The instance record's keys (`super::instance_keys`).
    pub(super) mask: Option<i64>,
    pub(super) custom_index: Option<i64>,
    pub(super) sbt_offset: Option<i64>,
    pub(super) flags: Option<Vec<String>>,
    pub(super) opaque: Option<bool>,
}

/// One `[[meshes.keyframes]]` entry; omitted fields are the identity.
#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct KeyframeDef {
    pub(super) time: f32,
    pub(super) translate: Option<[f32; 3]>,
    pub(super) rotate: Option<[f32; 3]>,
    pub(super) scale: Option<Vec3OrScalar>,
}
