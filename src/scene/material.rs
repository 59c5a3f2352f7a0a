//! Surface materials.
//!
//! One flat struct rather than an enum of material kinds: a Whitted-style
//! surface is a *sum* of responses (Bidmon (2010) adds direct light, the mirror
//! ray and the refracted ray), so any combination of diffuse, Phong
//! highlight, mirror, glossy, glass and emission must be expressible. The
//! renderer reads which terms are non-zero (see [`Material::reflects`] and
//! friends) to decide which kernels it needs.
//!
//! Response of a surface point, as the renderer is expected to evaluate it:
//!
//! ```text
//! L = emission
//!   + Σ_lights (diffuse · max(N·L, 0) + specular · max(R·L, 0)^shininess) · E_light
//!   + ambient · diffuse
//!   + mirror · L(reflected ray)                       [roughness spreads the lobe]
//!   + transmission · L(refracted ray, Snell with ior)  [· (1 − F) if fresnel]
//!   + transmission · F · L(reflected ray)              [only if fresnel]
//! ```
//!
//! where `F` is the Fresnel reflectance of the dielectric boundary (total
//! internal reflection gives `F = 1`). With `fresnel = false` the weights are
//! exactly Bidmon's (2010) `reflection` and `transparency`.

use glam::Vec3;

/// A surface material. Colours are linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name (from the scene file or MTL; may be empty for generated ones).
    pub name: String,
    /// Lambertian albedo, each channel ≥ 0 (normally ≤ 1).
    pub diffuse: Vec3,
    /// Phong highlight colour, each channel ≥ 0.
    pub specular: Vec3,
    /// Phong exponent, 0 ..= [`MAX_SHININESS`](super::MAX_SHININESS).
    pub shininess: f32,
    /// Mirror reflectance per channel, 0 ..= 1.
    pub mirror: Vec3,
    /// Glossiness of reflection and refraction, 0 ..= 1: 0 is a perfect
    /// mirror / clear glass; larger values widen the lobe (the renderer
    /// samples a cone whose half-angle grows with roughness).
    pub roughness: f32,
    /// Fraction of light refracted through the surface, 0 ..= 1.
    pub transmission: f32,
    /// Index of refraction of the inside medium (outside is 1), > 0.
    pub ior: f32,
    /// Whether the reflect/refract split of `transmission` follows the
    /// Fresnel equations (true, physically based glass) or uses the fixed
    /// weights (false, Bidmon's (2010) model).
    pub fresnel: bool,
    /// Emitted radiance, each channel ≥ 0.
    pub emission: Vec3,
}

impl Default for Material {
    fn default() -> Self {
        Self::diffuse("default", Vec3::splat(0.8))
    }
}

impl Material {
    /// A matte material.
    pub fn diffuse(name: &str, color: Vec3) -> Self {
        Self {
            name: name.to_owned(),
            diffuse: color,
            specular: Vec3::ZERO,
            shininess: 0.0,
            mirror: Vec3::ZERO,
            roughness: 0.0,
            transmission: 0.0,
            ior: 1.0,
            fresnel: true,
            emission: Vec3::ZERO,
        }
    }

    /// A perfect mirror with the given reflectance.
    pub fn mirror(name: &str, reflectance: Vec3) -> Self {
        Self {
            diffuse: Vec3::ZERO,
            mirror: reflectance,
            ..Self::diffuse(name, Vec3::ZERO)
        }
    }

    /// Clear glass with Fresnel reflection.
    pub fn glass(name: &str, ior: f32) -> Self {
        Self {
            diffuse: Vec3::ZERO,
            transmission: 1.0,
            ior,
            fresnel: true,
            ..Self::diffuse(name, Vec3::ZERO)
        }
    }

    /// An emitter (with black diffuse response).
    pub fn emissive(name: &str, radiance: Vec3) -> Self {
        Self {
            diffuse: Vec3::ZERO,
            emission: radiance,
            ..Self::diffuse(name, Vec3::ZERO)
        }
    }

    /// Bidmon's (2010) material (thesis Appendix B) for an object of colour
    /// `color`: `shininess` is the Phong exponent, `specular` scales a white
    /// highlight, `reflection` (0..1) is the mirror weight, `refraction` the
    /// index of refraction and `transparency` (0..1) the refracted weight.
    /// Fresnel is off: Bidmon (2010) uses fixed weights.
    pub fn scn(
        name: &str,
        color: Vec3,
        shininess: f32,
        specular: f32,
        reflection: f32,
        refraction: f32,
        transparency: f32,
    ) -> Self {
        Self {
            name: name.to_owned(),
            diffuse: color,
            specular: Vec3::splat(specular),
            shininess,
            mirror: Vec3::splat(reflection),
            roughness: 0.0,
            transmission: transparency,
            ior: refraction,
            fresnel: false,
            emission: Vec3::ZERO,
        }
    }

    /// Traces reflected rays: a mirror term, or glass with Fresnel.
    pub fn reflects(&self) -> bool {
        self.mirror.max_element() > 0.0 || (self.refracts() && self.fresnel)
    }

    /// Traces refracted rays.
    pub fn refracts(&self) -> bool {
        self.transmission > 0.0
    }

    /// Reflection or refraction is blurred (needs several samples).
    pub fn is_glossy(&self) -> bool {
        self.roughness > 0.0 && (self.reflects() || self.refracts())
    }

    /// Emits light.
    pub fn emits(&self) -> bool {
        self.emission.max_element() > 0.0
    }
}
