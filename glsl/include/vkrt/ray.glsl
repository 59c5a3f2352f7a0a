// Rays, hits and the primitive intersection tests, byte for byte and operation for operation
// the Rust twins in src/trace/intersect.rs (keep in sync). Every float expression that
// decides a hit is `precise`: no fused multiply-add, so the CPU twin sees the same rounding.
#ifndef VKRT_COMMON_RAY_GLSL
#define VKRT_COMMON_RAY_GLSL

// 32 bytes (std430): `VkrtRay` in src/trace/mod.rs.
struct VkrtRay {
    vec3 o;
    float tmin;
    vec3 d;
    float tmax;
};

// 16 bytes: `VkrtWalkHit` in src/trace/mod.rs. A miss has t = +inf and prim = VKRT_NO_HIT.
struct VkrtWalkHit {
    float t;
    uint prim;
    float u; // barycentric weight of the triangle's second vertex (sphere: 0)
    float v; // barycentric weight of the third vertex (sphere: 0)
};

#define VKRT_NO_HIT 0xffffffffu
#ifndef VKRT_FP64_FALLBACK
#define VKRT_FP64_FALLBACK 0
#endif
// gamma(n) = n u / (1 - n u), u = 2^-24 (pbrt's bound on n roundings), as exact bits.
#define VKRT_GAMMA2 uintBitsToFloat(0x34000001u)
#define VKRT_GAMMA3 uintBitsToFloat(0x34400002u)
#define VKRT_GAMMA5 uintBitsToFloat(0x34a00003u)
#define VKRT_GAMMA7 uintBitsToFloat(0x34e00006u)
#define VKRT_GAMMA8 uintBitsToFloat(0x35000004u)
#define VKRT_INTERSECT_WATERTIGHT 0u
#define VKRT_INTERSECT_MOLLER_TRUMBORE 1u

float vkrt_positive_inf() {
    return uintBitsToFloat(0x7f800000u);
}

VkrtWalkHit vkrt_miss_hit() {
    return VkrtWalkHit(vkrt_positive_inf(), VKRT_NO_HIT, 0.0, 0.0);
}

// Bit tests: the driver's compiler may assume no NaN in isnan/isinf.
bool vkrt_is_finite(float x) {
    return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u;
}

bool vkrt_is_finite3(vec3 v) {
    return vkrt_is_finite(v.x) && vkrt_is_finite(v.y) && vkrt_is_finite(v.z);
}

bool vkrt_is_nan(float x) {
    return (floatBitsToUint(x) & 0x7fffffffu) > 0x7f800000u;
}

#define VKRT_FLT_MIN uintBitsToFloat(0x00800000u)

// dot and cross in the CPU twins' order of operations (src/trace/intersect.rs): a driver may
// evaluate the builtins with fused multiply-adds even under `precise`.
float vkrt_dot3(vec3 a, vec3 b) {
    precise float r = a.x * b.x + a.y * b.y + a.z * b.z;
    return r;
}

vec3 vkrt_cross3(vec3 a, vec3 b) {
    precise vec3 r = vec3(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
    return r;
}

// The float next to x (normal, non-zero) towards +inf (up) or -inf.
float vkrt_next_toward(float x, bool up) {
    uint b = floatBitsToUint(x);
    return uintBitsToFloat((x > 0.0) == up ? b + 1u : b - 1u);
}

// Vulkan lets a driver's a / b be 2.5 ulp off and its sqrt 3 ulp (GPUs use reciprocals),
// while + - * round correctly. With doubles (the `exact` variants), division and square
// root round correctly too, as on the CPU: the driver's answer is checked against a residual
// that is exact in doubles (a product of two floats is) and moved to the nearer neighbour.
// Up to 7 ulps are corrected (the steps after the first are rare). Only normal results are
// refined (a device may flush subnormals to zero).
#ifndef VKRT_DRIVER_DIV
#define VKRT_DRIVER_DIV(a, b) ((a) / (b))
#endif
#ifndef VKRT_DRIVER_SQRT
#define VKRT_DRIVER_SQRT(x) sqrt(x)
#endif
#if VKRT_FP64_FALLBACK
// False where the driver's division and square root are known to round correctly
// (DeviceInfo::ieee_division): the check is then left out.
#if defined(VKRT_LIBRARY) && defined(VKRT_REFINE_DIVISION)
const bool VKRT_REFINE = VKRT_REFINE_DIVISION;
#elif defined(VKRT_LIBRARY)
const bool VKRT_REFINE = true;
#else
layout(constant_id = 21) const bool VKRT_REFINE = true;
#endif

bool vkrt_refinable(float x) {
    return vkrt_is_finite(x) && abs(x) >= uintBitsToFloat(0x03800000u); // 2^-120
}

float vkrt_div_rn(float a, float b) {
    precise float q = VKRT_DRIVER_DIV(a, b);
    if (!VKRT_REFINE || !vkrt_refinable(q) || !vkrt_is_finite(a) || !vkrt_is_finite(b)) {
        return q;
    }
    for (uint i = 0u; i < 8u; i++) {
        // a - q b is exact: q b has 48 significant bits and lies within a few ulps of a.
        precise double r = double(a) - double(q) * double(b);
        if (r == 0.0) {
            break;
        }
        float n = vkrt_next_toward(q, (r > 0.0) == (b > 0.0));
        precise double gap = abs(double(n) - double(q));
        // q is the nearest float to a / b when |a/b - q| < gap / 2 (never a tie: a quotient
        // of floats is never a midpoint).
        if (2.0 * abs(r) < abs(double(b)) * gap) {
            break;
        }
        q = n;
    }
    return q;
}

// Tuckerman's test: s rounds sqrt(x) to nearest iff s- s < x <= s s+ (products exact in
// doubles).
float vkrt_sqrt_rn(float x) {
    precise float s = VKRT_DRIVER_SQRT(x);
    if (!VKRT_REFINE || !(x > 0.0) || !vkrt_refinable(x) || !vkrt_refinable(s)) {
        return s;
    }
    for (uint i = 0u; i < 8u; i++) {
        float up = vkrt_next_toward(s, true);
        float down = vkrt_next_toward(s, false);
        if (double(x) > double(s) * double(up)) {
            s = up;
        } else if (double(x) <= double(down) * double(s)) {
            s = down;
        } else {
            break;
        }
    }
    return s;
}
#else
float vkrt_div_rn(float a, float b) {
    precise float q = VKRT_DRIVER_DIV(a, b);
    return q;
}

float vkrt_sqrt_rn(float x) {
    return VKRT_DRIVER_SQRT(x);
}
#endif

// 1 / d per axis (the slab tests' inverse direction).
vec3 vkrt_recip3(vec3 d) {
    return vec3(vkrt_div_rn(1.0, d.x), vkrt_div_rn(1.0, d.y), vkrt_div_rn(1.0, d.z));
}

// A ray the traversal accepts: finite origin, direction and tmin, a tmax that is not NaN
// (+inf is unbounded), a non-zero direction, tmin <= tmax. Everything else is answered as
// a miss (src/trace/mod.rs documents the contract).
bool vkrt_ray_is_valid(VkrtRay r) {
    return vkrt_is_finite3(r.o) && vkrt_is_finite3(r.d) && vkrt_is_finite(r.tmin) && !vkrt_is_nan(r.tmax)
        && (r.d.x != 0.0 || r.d.y != 0.0 || r.d.z != 0.0) && r.tmin <= r.tmax;
}

// Per-ray constants of the watertight test (Woop, Benthin, Wald 2013): the dominant axis kz,
// the other two (swapped to keep the winding), and the shear.
struct VkrtShear {
    uint kx;
    uint ky;
    uint kz;
    float sx;
    float sy;
    float sz;
};

uint vkrt_max_dim(vec3 v) {
    vec3 a = abs(v);
    return a.x >= a.y ? (a.x >= a.z ? 0u : 2u) : (a.y >= a.z ? 1u : 2u);
}

VkrtShear vkrt_make_shear(vec3 d) {
    VkrtShear s;
    s.kz = vkrt_max_dim(d);
    s.kx = s.kz == 2u ? 0u : s.kz + 1u;
    s.ky = s.kx == 2u ? 0u : s.kx + 1u;
    if (d[s.kz] < 0.0) {
        uint t = s.kx;
        s.kx = s.ky;
        s.ky = t;
    }
    precise float sx = vkrt_div_rn(d[s.kx], d[s.kz]);
    precise float sy = vkrt_div_rn(d[s.ky], d[s.kz]);
    precise float sz = vkrt_div_rn(1.0, d[s.kz]);
    s.sx = sx;
    s.sy = sy;
    s.sz = sz;
    return s;
}

// Watertight: a ray through a shared edge or vertex hits at least one of the triangles that
// share it (edge functions of zero count as inside on both sides, and a*b - c*d is the exact
// negation of c*d - a*b in IEEE arithmetic). Degenerate triangles (det = 0, or a zero
// cross product of the edges) never hit.
// `front`: whether the ray meets the triangle's front (the sheared determinant positive:
// its vertices counter-clockwise seen from the origin, Vulkan's facing before an instance
// flips it); set on a hit.
bool vkrt_hit_triangle_watertight_facing(vec3 o, VkrtShear s, vec3 p0, vec3 p1, vec3 p2, float tmin,
                                         float tmax, out float t, out float u, out float v,
                                         out bool front) {
    front = false;
    precise vec3 a = p0 - o;
    precise vec3 b = p1 - o;
    precise vec3 c = p2 - o;
    precise float ax = a[s.kx] - s.sx * a[s.kz];
    precise float ay = a[s.ky] - s.sy * a[s.kz];
    precise float bx = b[s.kx] - s.sx * b[s.kz];
    precise float by = b[s.ky] - s.sy * b[s.kz];
    precise float cx = c[s.kx] - s.sx * c[s.kz];
    precise float cy = c[s.ky] - s.sy * c[s.kz];
    precise float e0 = cx * by - cy * bx;
    precise float e1 = ax * cy - ay * cx;
    precise float e2 = bx * ay - by * ax;
#if VKRT_FP64_FALLBACK
    // An edge function that rounds to zero gets its exact sign from doubles (products of
    // floats are exact there): otherwise a grazing ray near an edge "hits" a triangle its
    // line passes beside, at a meaningless t (the paper's fallback).
    if (e0 == 0.0 || e1 == 0.0 || e2 == 0.0) {
        e0 = float(double(cx) * double(by) - double(cy) * double(bx));
        e1 = float(double(ax) * double(cy) - double(ay) * double(cx));
        e2 = float(double(bx) * double(ay) - double(by) * double(ax));
    }
#endif
    t = 0.0;
    u = 0.0;
    v = 0.0;
    if ((e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0)) {
        return false;
    }
    precise float det = e0 + e1 + e2;
    if (det == 0.0) {
        return false;
    }
    precise float az = s.sz * a[s.kz];
    precise float bz = s.sz * b[s.kz];
    precise float cz = s.sz * c[s.kz];
    precise float tt = e0 * az + e1 * bz + e2 * cz;
    precise float hit_t = vkrt_div_rn(tt, det);
    if (!(hit_t >= tmin && hit_t <= tmax)) {
        return false;
    }
    // A triangle of zero area (collinear or repeated vertices: the edges' cross product is
    // exactly zero) passes the 2-D test by rounding when the ray crosses its line, at a
    // meaningless t: it never hits. Tested only for candidates that passed everything else.
    precise vec3 n = vkrt_cross3(p1 - p0, p2 - p0);
    if (n.x == 0.0 && n.y == 0.0 && n.z == 0.0) {
        return false;
    }
    precise float inv = vkrt_div_rn(1.0, det);
    // Conservative t (pbrt-v3 3.9.6): a hit closer than the rounding bound of the computed
    // t may lie behind the origin (a spawned ray re-hitting its own surface): rejected.
    // The bounds of the sheared x and y use the unscaled z (pbrt uses the z scaled by
    // 1/d[kz], which is only commensurate for directions of length about 1), and only as
    // much of it as the shear takes in: every error z brings into x' = x - sx z comes
    // multiplied by |sx| (pbrt bounds |sx| by 1, which rejects a unit triangle 2^19 units
    // down an axis-parallel ray).
    precise float max_zt = max(max(abs(az), abs(bz)), abs(cz));
    precise float max_zu = max(max(abs(a[s.kz]), abs(b[s.kz])), abs(c[s.kz]));
    precise float max_xt = max(max(abs(ax), abs(bx)), abs(cx));
    precise float max_yt = max(max(abs(ay), abs(by)), abs(cy));
    precise float delta_z = VKRT_GAMMA3 * max_zt;
    precise float delta_x = VKRT_GAMMA5 * (max_xt + abs(s.sx) * max_zu);
    precise float delta_y = VKRT_GAMMA5 * (max_yt + abs(s.sy) * max_zu);
    precise float delta_e = 2.0 * (VKRT_GAMMA2 * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    precise float max_e = max(max(abs(e0), abs(e1)), abs(e2));
    precise float delta_t =
        3.0 * (VKRT_GAMMA3 * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * abs(inv);
    if (hit_t <= delta_t) {
        return false;
    }
    t = hit_t;
    u = e1 * inv;
    v = e2 * inv;
    front = det > 0.0;
    return true;
}

bool vkrt_hit_triangle_watertight(vec3 o, VkrtShear s, vec3 p0, vec3 p1, vec3 p2, float tmin,
                             float tmax, out float t, out float u, out float v) {
    bool front;
    return vkrt_hit_triangle_watertight_facing(o, s, p0, p1, p2, tmin, tmax, t, u, v, front);
}

// Möller–Trumbore (1997): fewer operations, not watertight (rays through shared edges can
// slip between triangles); kept for the robustness comparison.
bool vkrt_hit_triangle_moller(vec3 o, vec3 d, vec3 p0, vec3 p1, vec3 p2, float tmin, float tmax,
                         out float t, out float u, out float v) {
    precise vec3 e1 = p1 - p0;
    precise vec3 e2 = p2 - p0;
    precise vec3 pv = vkrt_cross3(d, e2);
    precise float det = vkrt_dot3(e1, pv);
    t = 0.0;
    u = 0.0;
    v = 0.0;
    if (det == 0.0) {
        return false;
    }
    precise float inv = vkrt_div_rn(1.0, det);
    precise vec3 tv = o - p0;
    precise float uu = vkrt_dot3(tv, pv) * inv;
    if (uu < 0.0 || uu > 1.0) {
        return false;
    }
    precise vec3 qv = vkrt_cross3(tv, e1);
    precise float vv = vkrt_dot3(d, qv) * inv;
    if (vv < 0.0 || uu + vv > 1.0) {
        return false;
    }
    precise float hit_t = vkrt_dot3(e2, qv) * inv;
    if (!(hit_t >= tmin && hit_t <= tmax)) {
        return false;
    }
    t = hit_t;
    u = uu;
    v = vv;
    return true;
}

// VkrtRay/sphere after Haines et al., "Precision Improvements for VkrtRay/Sphere Intersection"
// (VkrtRay Tracing Gems ch. 7): the discriminant from the distance of the centre to the ray
// line (no catastrophic cancellation far from the sphere) and the stable quadratic roots.
bool vkrt_hit_sphere(vec3 o, vec3 d, vec4 sphere, float tmin, float tmax, out float t) {
    precise vec3 f = o - sphere.xyz;
    precise float a = vkrt_dot3(d, d);
    precise float bp = -vkrt_dot3(f, d);
    precise vec3 l = f + vkrt_div_rn(bp, a) * d;
    precise float r2 = sphere.w * sphere.w;
    precise float disc = r2 - vkrt_dot3(l, l);
    t = 0.0;
    if (disc < 0.0) {
        return false;
    }
    precise float c = vkrt_dot3(f, f) - r2;
    precise float q = bp + (bp >= 0.0 ? 1.0 : -1.0) * vkrt_sqrt_rn(a * disc);
    if (q == 0.0) {
        return false;
    }
    precise float t0 = vkrt_div_rn(c, q);
    precise float t1 = vkrt_div_rn(q, a);
    float lo = min(t0, t1);
    float hi = max(t0, t1);
    if (lo >= tmin && lo <= tmax) {
        t = lo;
        return true;
    }
    if (hi >= tmin && hi <= tmax) {
        t = hi;
        return true;
    }
    return false;
}

// VkrtRay/axis-aligned box [lo, hi] (a box primitive): where the ray enters the box, or leaves
// it when it starts inside, within [tmin, tmax]; intersect::aabb in src/trace/intersect.rs.
// A box with lo > hi on an axis (inactive) is never hit. Minima and maxima are comparisons,
// not min/max, so that +-0 resolve as in the twin.
// One axis of vkrt_hit_aabb: narrows [near, far] to the slab; false when the ray misses it.
bool vkrt_aabb_slab(float o, float d, float lo, float hi, inout float near, inout float far) {
    if (d == 0.0) {
        return !(o < lo || o > hi);
    }
    precise float a = vkrt_div_rn(lo - o, d);
    precise float b = vkrt_div_rn(hi - o, d);
    float n = a < b ? a : b;
    float f = a < b ? b : a;
    near = n > near ? n : near;
    far = f < far ? f : far;
    return true;
}

// No loop over the axes: llvmpipe before Mesa 25 counts every iteration of every loop,
// even in a branch no lane takes, against its budget of 65,535 per invocation, and this
// test is compiled into every primitive test of the walk.
bool vkrt_hit_aabb(vec3 o, vec3 d, vec3 lo, vec3 hi, float tmin, float tmax, out float t) {
    t = 0.0;
    if (!all(lessThanEqual(lo, hi))) {
        return false;
    }
    float near = uintBitsToFloat(0xff800000u);
    float far = uintBitsToFloat(0x7f800000u);
    if (!vkrt_aabb_slab(o.x, d.x, lo.x, hi.x, near, far) || !vkrt_aabb_slab(o.y, d.y, lo.y, hi.y, near, far)
        || !vkrt_aabb_slab(o.z, d.z, lo.z, hi.z, near, far)) {
        return false;
    }
    if (near > far) {
        return false;
    }
    if (near >= tmin && near <= tmax) {
        t = near;
        return true;
    }
    if (far >= tmin && far <= tmax) {
        t = far;
        return true;
    }
    return false;
}

// The outward normal of the face of box [lo, hi] that `p` lies on (the axis where p is
// nearest a face; ties: x, y, z, min face first); intersect::vkrt_aabb_normal.
vec3 vkrt_aabb_normal(vec3 lo, vec3 hi, vec3 p) {
    float best = uintBitsToFloat(0x7f800000u);
    vec3 n = vec3(1.0, 0.0, 0.0);
    for (int k = 0; k < 3; k++) {
        float dl = abs(p[k] - lo[k]);
        if (dl < best) {
            best = dl;
            n = vec3(0.0);
            n[k] = -1.0;
        }
        float dh = abs(p[k] - hi[k]);
        if (dh < best) {
            best = dh;
            n = vec3(0.0);
            n[k] = 1.0;
        }
    }
    return n;
}

// A ray origin moved off a surface along its geometric normal `n` (pointing to the side the
// new ray leaves on) by a few ulps of the position, not a fixed epsilon: Wächter & Binder,
// "A Fast and Robust Method for Avoiding Self-Intersection" (VkrtRay Tracing Gems ch. 6).
vec3 vkrt_offset_ray_origin(vec3 p, vec3 n) {
    const float origin = 1.0 / 32.0;
    const float float_scale = 1.0 / 65536.0;
    const float int_scale = 256.0;
    ivec3 of = ivec3(int_scale * n);
    vec3 pi = vec3(
        intBitsToFloat(floatBitsToInt(p.x) + (p.x < 0.0 ? -of.x : of.x)),
        intBitsToFloat(floatBitsToInt(p.y) + (p.y < 0.0 ? -of.y : of.y)),
        intBitsToFloat(floatBitsToInt(p.z) + (p.z < 0.0 ? -of.z : of.z)));
    precise vec3 pf = p + float_scale * n;
    return vec3(abs(p.x) < origin ? pf.x : pi.x,
                abs(p.y) < origin ? pf.y : pi.y,
                abs(p.z) < origin ? pf.z : pi.z);
}

// The next float towards +inf / -inf (finite x).
// Never a subnormal (a device may flush them to zero): above zero and the subnormals is the
// smallest normal float, above -VKRT_FLT_MIN is zero (next_up in src/accel/primitives.rs).
float vkrt_next_float_up(float x) {
    if (abs(x) < VKRT_FLT_MIN) {
        return VKRT_FLT_MIN;
    }
    if (x == -VKRT_FLT_MIN) {
        return -0.0;
    }
    uint b = floatBitsToUint(x);
    return uintBitsToFloat(x > 0.0 ? b + 1u : b - 1u);
}

float vkrt_next_float_down(float x) {
    return -vkrt_next_float_up(-x);
}

// A spawned ray's origin from a point `p` with a bound `err` on its rounding error (per
// axis): moved along the unit normal `n` (pointing to the side the ray leaves on) past the
// error box, then one float further away (pbrt-v4 OffsetRayOrigin). Sound when the error
// of p is not proportional to |p| (a hit point interpolated from vertices far larger than
// itself), where vkrt_offset_ray_origin's few ulps of p are not enough.
vec3 vkrt_offset_ray_origin_bounded(vec3 p, vec3 n, vec3 err) {
    precise float d = vkrt_dot3(abs(n), err);
    precise vec3 off = d * n;
    precise vec3 po = p + off;
    for (uint i = 0u; i < 3u; i++) {
        if (off[i] > 0.0) {
            po[i] = vkrt_next_float_up(po[i]);
        } else if (off[i] < 0.0) {
            po[i] = vkrt_next_float_down(po[i]);
        }
    }
    return po;
}

// A triangle hit point from its barycentrics and its error bound (pbrt-v4 3.9.4).
vec3 vkrt_triangle_hit_point(vec3 p0, vec3 p1, vec3 p2, float u, float v, out vec3 err) {
    precise float b0 = 1.0 - u - v;
    precise vec3 p = b0 * p0 + u * p1 + v * p2;
    precise vec3 e = VKRT_GAMMA7 * (abs(b0 * p0) + abs(u * p1) + abs(v * p2));
    err = e;
    return p;
}

// A sphere hit point `p` re-projected onto the sphere (centre c, radius r) and an error
// bound that also covers the ray/sphere test's own rounding (about 3 u r).
vec3 vkrt_sphere_hit_point(vec3 c, float r, vec3 p, out vec3 err) {
    precise vec3 q = c + (p - c) * vkrt_div_rn(r, vkrt_sqrt_rn(vkrt_dot3(p - c, p - c)));
    precise vec3 e = VKRT_GAMMA8 * (vec3(r) + abs(q));
    err = e;
    return q;
}

#endif
