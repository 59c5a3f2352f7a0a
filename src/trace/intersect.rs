//! CPU twins of the intersection tests in `glsl/include/vkrt/ray.glsl`: the same operations in the
//! same order (no fused multiply-add on either side).

use glam::{Vec3, Vec4};

/// `gamma(n) = n u / (1 - n u)`, `u = 2^-24`: pbrt's bound on the relative error of `n`
/// roundings (`GAMMAn` in `ray.glsl`, the same bits).
pub const GAMMA2: f32 = f32::from_bits(0x3400_0001);
/// `gamma(3)` (see [`GAMMA2`]): the watertight test's bounds on z and on `t`.
pub const GAMMA3: f32 = f32::from_bits(0x3440_0002);
/// `gamma(5)` (see [`GAMMA2`]): the watertight test's bounds on the sheared x and y.
pub const GAMMA5: f32 = f32::from_bits(0x34a0_0003);
/// `gamma(7)` (see [`GAMMA2`]): the error bound of a triangle hit point
/// ([`triangle_hit_point`]).
pub const GAMMA7: f32 = f32::from_bits(0x34e0_0006);
/// `gamma(8)` (see [`GAMMA2`]): the error bound of a sphere hit point
/// ([`sphere_hit_point`]).
pub const GAMMA8: f32 = f32::from_bits(0x3500_0004);

/// The per-ray shear of the watertight test.
#[derive(Clone, Copy, Debug)]
pub struct Shear {
    /// The first axis of the sheared plane (swapped with `ky` when `d[kz] < 0`, to keep
    /// the triangles' winding).
    pub kx: usize,
    /// The second axis of the sheared plane.
    pub ky: usize,
    /// The axis where the direction's magnitude is largest (ties: x, then y).
    pub kz: usize,
    /// `d[kx] / d[kz]`.
    pub sx: f32,
    /// `d[ky] / d[kz]`.
    pub sy: f32,
    /// `1 / d[kz]`.
    pub sz: f32,
}

fn max_dim(v: Vec3) -> usize {
    let a = v.abs();
    if a.x >= a.y {
        if a.x >= a.z {
            0
        } else {
            2
        }
    } else if a.y >= a.z {
        1
    } else {
        2
    }
}

impl Shear {
    /// The shear of a ray with direction `d` (non-zero), computed once per ray.
    pub fn new(d: Vec3) -> Self {
        let kz = max_dim(d);
        let mut kx = if kz == 2 { 0 } else { kz + 1 };
        let mut ky = if kx == 2 { 0 } else { kx + 1 };
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Self {
            kx,
            ky,
            kz,
            sx: d[kx] / d[kz],
            sy: d[ky] / d[kz],
            sz: 1.0 / d[kz],
        }
    }
}

/// A hit's `t` and the barycentric weights of the second and third vertex.
pub type TriHit = (f32, f32, f32);

/// Watertight ray/triangle test (Woop, Benthin & Wald 2013); see `ray.glsl`. `exact`: the
/// double-precision fallback for edge functions that round to zero (`VKRT_FP64_FALLBACK`).
#[allow(clippy::too_many_arguments)]
pub fn triangle_watertight(
    exact: bool,
    o: Vec3,
    s: &Shear,
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<TriHit> {
    let (a, b, c) = (p0 - o, p1 - o, p2 - o);
    let ax = a[s.kx] - s.sx * a[s.kz];
    let ay = a[s.ky] - s.sy * a[s.kz];
    let bx = b[s.kx] - s.sx * b[s.kz];
    let by = b[s.ky] - s.sy * b[s.kz];
    let cx = c[s.kx] - s.sx * c[s.kz];
    let cy = c[s.ky] - s.sy * c[s.kz];
    let (mut e0, mut e1, mut e2) = (cx * by - cy * bx, ax * cy - ay * cx, bx * ay - by * ax);
    if exact && (e0 == 0.0 || e1 == 0.0 || e2 == 0.0) {
        let d = |a: f32, b: f32, c: f32, e: f32| (a as f64 * b as f64 - c as f64 * e as f64) as f32;
        (e0, e1, e2) = (d(cx, by, cy, bx), d(ax, cy, ay, cx), d(bx, ay, by, ax));
    }
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
        return None;
    }
    let det = e0 + e1 + e2;
    if det == 0.0 {
        return None;
    }
    let (az, bz, cz) = (s.sz * a[s.kz], s.sz * b[s.kz], s.sz * c[s.kz]);
    let tt = e0 * az + e1 * bz + e2 * cz;
    let t = tt / det;
    if !(t >= tmin && t <= tmax) {
        return None;
    }
    // Zero area (collinear or repeated vertices): never a hit, whatever the rounding says.
    if cross(p1 - p0, p2 - p0) == Vec3::ZERO {
        return None;
    }
    let inv = 1.0 / det;
    // Conservative t (pbrt-v3 3.9.6): see `ray.glsl`.
    let max_zt = az.abs().max(bz.abs()).max(cz.abs());
    let max_zu = a[s.kz].abs().max(b[s.kz].abs()).max(c[s.kz].abs());
    let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
    let max_yt = ay.abs().max(by.abs()).max(cy.abs());
    let delta_z = GAMMA3 * max_zt;
    // Errors from z enter x' = x - sx z times |sx| (see `ray.glsl`).
    let delta_x = GAMMA5 * (max_xt + s.sx.abs() * max_zu);
    let delta_y = GAMMA5 * (max_yt + s.sy.abs() * max_zu);
    let delta_e = 2.0 * (GAMMA2 * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t = 3.0 * (GAMMA3 * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv.abs();
    if t <= delta_t {
        return None;
    }
    Some((t, e1 * inv, e2 * inv))
}

fn dot(a: Vec3, b: Vec3) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    Vec3::new(
        a.y * b.z - b.y * a.z,
        a.z * b.x - b.z * a.x,
        a.x * b.y - b.x * a.y,
    )
}

/// Möller–Trumbore (not watertight); see `ray.glsl`.
#[allow(clippy::too_many_arguments)]
pub fn triangle_moller(
    o: Vec3,
    d: Vec3,
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<TriHit> {
    let e1 = p1 - p0;
    let e2 = p2 - p0;
    let pv = cross(d, e2);
    let det = dot(e1, pv);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let tv = o - p0;
    let u = dot(tv, pv) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let qv = cross(tv, e1);
    let v = dot(d, qv) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dot(e2, qv) * inv;
    if !(t >= tmin && t <= tmax) {
        return None;
    }
    Some((t, u, v))
}

/// Ray/sphere (Haines et al., Ray Tracing Gems ch. 7); `sphere` = centre, radius.
pub fn sphere(o: Vec3, d: Vec3, sphere: Vec4, tmin: f32, tmax: f32) -> Option<f32> {
    let f = o - sphere.truncate();
    let a = dot(d, d);
    let bp = -dot(f, d);
    let l = f + (bp / a) * d;
    let r2 = sphere.w * sphere.w;
    let disc = r2 - dot(l, l);
    if disc < 0.0 {
        return None;
    }
    let c = dot(f, f) - r2;
    let q = bp + if bp >= 0.0 { 1.0 } else { -1.0 } * (a * disc).sqrt();
    if q == 0.0 {
        return None;
    }
    let (t0, t1) = (c / q, q / a);
    let (lo, hi) = (t0.min(t1), t0.max(t1));
    if lo >= tmin && lo <= tmax {
        Some(lo)
    } else if hi >= tmin && hi <= tmax {
        Some(hi)
    } else {
        None
    }
}

/// Ray/axis-aligned box `[lo, hi]` (a box primitive): where the ray enters the box, or
/// leaves it when it starts inside, within `[tmin, tmax]`; `hit_aabb` in `ray.glsl`. A box
/// with `lo > hi` (or NaN) on an axis is never hit. Minima and maxima are comparisons, not
/// `min`/`max`, so that ±0 resolve the same way on every device.
pub fn aabb(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3, tmin: f32, tmax: f32) -> Option<f32> {
    if !lo.cmple(hi).all() {
        return None;
    }
    let (mut near, mut far) = (f32::NEG_INFINITY, f32::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let a = (lo[k] - o[k]) / d[k];
        let b = (hi[k] - o[k]) / d[k];
        let (n, f) = if a < b { (a, b) } else { (b, a) };
        near = if n > near { n } else { near };
        far = if f < far { f } else { far };
    }
    if near > far {
        None
    } else if near >= tmin && near <= tmax {
        Some(near)
    } else if far >= tmin && far <= tmax {
        Some(far)
    } else {
        None
    }
}

/// The outward normal of the face of box `[lo, hi]` that point `p` lies on (the axis where
/// `p` is nearest a face; ties: x before y before z).
pub fn aabb_normal(lo: Vec3, hi: Vec3, p: Vec3) -> Vec3 {
    let mut best = f32::INFINITY;
    let mut n = Vec3::X;
    for k in 0..3 {
        for (face, sign) in [(lo[k], -1.0), (hi[k], 1.0)] {
            let d = (p[k] - face).abs();
            if d < best {
                best = d;
                n = Vec3::ZERO;
                n[k] = sign;
            }
        }
    }
    n
}

/// A spawned ray's origin, moved off the surface at `p` along the geometric normal `n`
/// (pointing to the side the ray leaves on) by a few ulps of `p` (Wächter & Binder, Ray
/// Tracing Gems ch. 6); `offset_ray_origin` in `ray.glsl`.
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let mut out = Vec3::ZERO;
    for a in 0..3 {
        let of = (INT_SCALE * n[a]) as i32;
        let bits = p[a].to_bits() as i32;
        let pi = f32::from_bits(bits.wrapping_add(if p[a] < 0.0 { -of } else { of }) as u32);
        let pf = p[a] + FLOAT_SCALE * n[a];
        out[a] = if p[a].abs() < ORIGIN { pf } else { pi };
    }
    out
}

/// A spawned ray's origin from a point `p` with a bound `err` on its rounding error (per
/// axis): moved along the unit normal `n` (pointing to the side the ray leaves on) past the
/// error box, then one float further (pbrt-v4 `OffsetRayOrigin`); `offset_ray_origin_bounded`
/// in `ray.glsl`. Use it where the error of `p` is not proportional to `|p|` — a hit point
/// interpolated from vertices much farther from the world origin than itself — where
/// [`offset_ray_origin`]'s few ulps of `p` are not enough (see `trace::robust`).
pub fn offset_ray_origin_bounded(p: Vec3, n: Vec3, err: Vec3) -> Vec3 {
    let d = dot(n.abs(), err);
    let off = n * d;
    let mut po = p + off;
    for i in 0..3 {
        if off[i] > 0.0 {
            po[i] = crate::accel::primitives::next_up(po[i]);
        } else if off[i] < 0.0 {
            po[i] = crate::accel::primitives::next_down(po[i]);
        }
    }
    po
}

/// A triangle hit point from the barycentric weights `u`, `v` of its second and third
/// vertex, and the bound on its rounding error (pbrt-v4 3.9.4); `triangle_hit_point` in
/// `ray.glsl`.
pub fn triangle_hit_point(p0: Vec3, p1: Vec3, p2: Vec3, u: f32, v: f32) -> (Vec3, Vec3) {
    let b0 = 1.0 - u - v;
    let p = b0 * p0 + u * p1 + v * p2;
    let err = GAMMA7 * ((b0 * p0).abs() + (u * p1).abs() + (v * p2).abs());
    (p, err)
}

/// A point `p` near the sphere (centre `c`, radius `r`) re-projected onto it, and an error
/// bound that also covers the ray/sphere test's own rounding (about 3 u r);
/// `sphere_hit_point` in `ray.glsl`.
pub fn sphere_hit_point(c: Vec3, r: f32, p: Vec3) -> (Vec3, Vec3) {
    let q = c + (p - c) * (r / (p - c).length());
    let err = GAMMA8 * (Vec3::splat(r) + q.abs());
    (q, err)
}
