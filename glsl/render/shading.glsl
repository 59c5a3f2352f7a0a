// Sampling and BSDF helpers of the shade kernel; src/render/cpu.rs mirrors every function.
#ifndef VKRT_RENDER_SHADING_GLSL
#define VKRT_RENDER_SHADING_GLSL

#define PI 3.14159265358979

// An orthonormal basis around unit n (Duff et al. 2017).
void basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

vec3 around(vec3 n, vec3 local) {
    vec3 t, b;
    basis(n, t, b);
    return normalize(t * local.x + b * local.y + n * local.z);
}

// Cosine-weighted direction about n.
vec3 sample_cosine(vec3 n, inout uint s) {
    float r1 = rnd(s);
    float r2 = rnd(s);
    float phi = 2.0 * PI * r1;
    float r = sqrt(r2);
    return around(n, vec3(r * cos(phi), r * sin(phi), sqrt(max(0.0, 1.0 - r2))));
}

// Uniform direction in the cone of half-angle `roughness · π/4` about axis.
vec3 sample_cone(vec3 axis, float roughness, inout uint s) {
    float r1 = rnd(s);
    float r2 = rnd(s);
    float cos_max = cos(roughness * 0.25 * PI);
    float z = 1.0 - r1 * (1.0 - cos_max);
    float r = sqrt(max(0.0, 1.0 - z * z));
    float phi = 2.0 * PI * r2;
    return around(axis, vec3(r * cos(phi), r * sin(phi), z));
}

// Uniform unit vector.
vec3 sample_sphere(inout uint s) {
    float z = 1.0 - 2.0 * rnd(s);
    float r = sqrt(max(0.0, 1.0 - z * z));
    float phi = 2.0 * PI * rnd(s);
    return vec3(r * cos(phi), r * sin(phi), z);
}

vec3 reflect_dir(vec3 d, vec3 n) {
    return d - 2.0 * dot(d, n) * n;
}

// Fresnel reflectance of a dielectric boundary; eta = n_incident / n_transmitted, cos_i >= 0.
// 1 under total internal reflection.
float fresnel(float cos_i, float eta) {
    float sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if (sin2_t >= 1.0) {
        return 1.0;
    }
    float cos_t = sqrt(1.0 - sin2_t);
    float rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    float rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// Refracted direction of unit d through the boundary with unit normal n facing d's origin
// side; false under total internal reflection.
bool refract_dir(vec3 d, vec3 n, float eta, out vec3 t) {
    float c = -dot(d, n);
    float k = 1.0 - eta * eta * (1.0 - c * c);
    t = vec3(0.0);
    if (k < 0.0) {
        return false;
    }
    t = normalize(eta * d + (eta * c - sqrt(k)) * n);
    return true;
}

#endif
