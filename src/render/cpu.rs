//! CPU twin of the wavefront renderer: the same waves, bounces, random streams, shading and
//! accumulation order as the kernels in `glsl/render/` (transcendentals and traversal ties
//! may differ in the last bits, so images agree within a tolerance, not bit for bit).

use glam::{Vec3, Vec4};

use super::plan::Plan;
use super::types::*;
use super::{RayCounts, RenderAccel, RenderScene};
use crate::accel::device::AccelKind;
use crate::accel::host::HostStructure;
use crate::accel::primitives::{TraceGeometry, NO_MOTION};
use crate::accel::walk::AccelTraversal;
use crate::trace::bvh_cpu;
use crate::trace::cpu::{self, TraceScene};
use crate::trace::intersect::offset_ray_origin;
use crate::trace::{Hit, Query, Ray, TraceOptions};

/// tmax of unbounded rays (camera, reflection, refraction, directional-light shadows).
const FAR: f32 = f32::INFINITY;
const PI: f32 = std::f32::consts::PI;

fn v3(a: [f32; 4]) -> Vec3 {
    Vec3::new(a[0], a[1], a[2])
}

fn basis(n: Vec3) -> (Vec3, Vec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let c = n.x * n.y * a;
    (
        Vec3::new(1.0 + s * n.x * n.x * a, s * c, -s * n.x),
        Vec3::new(c, s + n.y * n.y * a, -n.y),
    )
}

fn around(n: Vec3, l: Vec3) -> Vec3 {
    let (t, b) = basis(n);
    (t * l.x + b * l.y + n * l.z).normalize()
}

fn sample_cosine(n: Vec3, s: &mut u32) -> Vec3 {
    let r1 = rnd(s);
    let r2 = rnd(s);
    let phi = 2.0 * PI * r1;
    let r = r2.sqrt();
    around(
        n,
        Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - r2).max(0.0).sqrt()),
    )
}

fn sample_cone(axis: Vec3, roughness: f32, s: &mut u32) -> Vec3 {
    let r1 = rnd(s);
    let r2 = rnd(s);
    let cos_max = (roughness * 0.25 * PI).cos();
    let z = 1.0 - r1 * (1.0 - cos_max);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * r2;
    around(axis, Vec3::new(r * phi.cos(), r * phi.sin(), z))
}

fn sample_sphere(s: &mut u32) -> Vec3 {
    let z = 1.0 - 2.0 * rnd(s);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * rnd(s);
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn reflect_dir(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

fn fresnel(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}

fn refract_dir(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let c = -d.dot(n);
    let k = 1.0 - eta * eta * (1.0 - c * c);
    (k >= 0.0).then(|| (eta * d + (eta * c - k.sqrt()) * n).normalize())
}

/// A CPU render: mean radiance per pixel and the ray counts.
pub struct CpuRender {
    /// Mean radiance per pixel (linear), row-major from the top-left.
    pub radiance: Vec<[f32; 3]>,
    /// Rays traced per kind.
    pub counts: RayCounts,
}

struct Shaded {
    radiance: Vec3,
    shadows: Vec<ShadowRay>,
    children: [Option<PathRay>; 2],
}

/// The host build of the structure the GPU renderer builds on the device for `kind`.
fn host_twin(kind: AccelKind, g: &TraceGeometry) -> RenderAccel {
    let twin = crate::accel::host::host_twin(kind, g, &Default::default());
    RenderAccel::Host(twin.expect("the scene's boxes are finite"))
}

/// Renders `rs` for `plan` on the host, tracing with the CPU twin of the plan's walk
/// (a structure the GPU builds on the device is built here by its host twin);
/// `trace_opt` picks the intersector.
pub fn render(rs: &RenderScene, plan: &Plan, trace_opt: &TraceOptions) -> CpuRender {
    let prm = &rs.params;
    let n_pixels = (prm.width * prm.height) as usize;
    let mut accum = vec![Vec3::ZERO; n_pixels];
    let mut counts = RayCounts::default();
    // A structure the GPU builds on the device: its CPU twin builds the same one here
    // (Kolodzey's CPU build is bit-exact with the GPU's; the SAH BVH is deterministic).
    let host = match &rs.accel {
        RenderAccel::OnDevice(choice) => Some(host_twin(choice.kind, &rs.geometry)),
        _ => None,
    };
    let accel = host.as_ref().unwrap_or(&rs.accel);
    // The structure's CPU twin walk, as the plan's kernels walk it.
    let trace = |r: &Ray, time: f32, opt: &TraceOptions| match (accel, plan.accel.traversal()) {
        (RenderAccel::Host(HostStructure::KdTree(tree)), _) => {
            let scene = TraceScene {
                geometry: &rs.geometry,
                tree,
            };
            cpu::trace(&scene, r, time, opt)
        }
        (RenderAccel::Host(HostStructure::Bvh(bvh)), AccelTraversal::Bvh(walk)) => {
            bvh_cpu::trace(&rs.geometry, bvh, r, time, opt, walk)
        }
        // A BVH stands in for the driver's structure, whose walk has no twin.
        (
            RenderAccel::Host(HostStructure::Bvh(bvh)),
            AccelTraversal::KdTree | AccelTraversal::RayQuery,
        ) => bvh_cpu::trace(&rs.geometry, bvh, r, time, opt, Default::default()),
        (RenderAccel::OnDevice(_), _) => unreachable!("resolved to its host twin above"),
    };
    let closest = TraceOptions {
        query: Query::Closest,
        ..*trace_opt
    };
    let any = TraceOptions {
        query: Query::Any,
        ..*trace_opt
    };
    let total = n_pixels as u32;
    for sample in 0..plan.spp {
        // Waves only bound memory: a pixel's rays never cross waves, so the image does not
        // depend on their size (the GPU shrinks them on overflow).
        for wave in 0..plan.waves() {
            let first = wave * plan.wave_pixels;
            let pixels = (total - first).min(plan.wave_pixels);
            let mut queue: Vec<PathRay> = (0..pixels)
                .map(|i| camera_ray(plan, prm, first + i, sample))
                .collect();
            counts.primary += pixels as u64;
            for depth in 0..=plan.max_depth {
                let spawn = plan.bounces && depth < plan.max_depth;
                let shaded: Vec<Shaded> = queue
                    .iter()
                    .map(|p| {
                        let (h, _) = trace(&as_ray(p.o, p.tmin, p.d, p.tmax), p.time, &closest);
                        let mut s = shade(rs, plan, p, &h);
                        for sh in s.shadows.iter_mut() {
                            if sh.kind == SHADOW_NONE {
                                continue;
                            }
                            if sh.kind == SHADOW_AO {
                                counts.ambient_occlusion += 1;
                            } else {
                                counts.shadow += 1;
                            }
                            let (o, _) = trace(&as_ray(sh.o, sh.tmin, sh.d, sh.tmax), p.time, &any);
                            if o.is_hit() {
                                sh.contrib = [0.0; 3];
                            }
                        }
                        s
                    })
                    .collect();
                // accumulate: per pixel run, in queue order
                let mut i = 0;
                while i < queue.len() {
                    let pixel = queue[i].pixel;
                    let mut sum = Vec3::ZERO;
                    let mut j = i;
                    while j < queue.len() && queue[j].pixel == pixel {
                        sum += shaded[j].radiance;
                        for s in &shaded[j].shadows {
                            if s.kind != SHADOW_NONE {
                                sum += Vec3::from_array(s.contrib);
                            }
                        }
                        j += 1;
                    }
                    accum[pixel as usize] += sum;
                    i = j;
                }
                if !spawn {
                    break;
                }
                let next: Vec<PathRay> = shaded
                    .iter()
                    .flat_map(|s| s.children.iter().flatten().copied())
                    .collect();
                for c in &next {
                    match c.kind {
                        RAY_REFLECTION => counts.reflection += 1,
                        RAY_REFRACTION => counts.refraction += 1,
                        _ => counts.glossy += 1,
                    }
                }
                queue = next;
            }
        }
    }
    let inv = 1.0 / plan.spp as f32;
    CpuRender {
        radiance: accum.iter().map(|a| (*a * inv).to_array()).collect(),
        counts,
    }
}

fn as_ray(o: [f32; 3], tmin: f32, d: [f32; 3], tmax: f32) -> Ray {
    Ray {
        origin: o,
        tmin,
        dir: d,
        tmax,
    }
}

/// `camera.comp`.
pub fn camera_ray(plan: &Plan, prm: &RenderParams, pixel: u32, sample: u32) -> PathRay {
    let mut seed = pcg(pixel ^ pcg(sample.wrapping_mul(0x9E37_79B9).wrapping_add(0x632B_E5AB)));
    let (mut jx, mut jy) = (0.5, 0.5);
    if plan.jitter && prm.jitter != 0 {
        jx = rnd(&mut seed);
        jy = rnd(&mut seed);
    }
    let x = (pixel % prm.width) as f32 + jx;
    let y = (pixel / prm.width) as f32 + jy;
    let sx = 2.0 * x / prm.width as f32 - 1.0;
    let sy = 1.0 - 2.0 * y / prm.height as f32;
    let fwd = v3(prm.cam_forward);
    let dir = fwd + sx * v3(prm.cam_right) + sy * v3(prm.cam_up);
    let mut d = dir.normalize();
    let mut o = v3(prm.cam_pos);
    if plan.thin_lens && prm.aperture > 0.0 {
        let r = prm.aperture * rnd(&mut seed).sqrt();
        let phi = 2.0 * PI * rnd(&mut seed);
        let focus = o + d * (prm.focus_distance / d.dot(fwd));
        let right = v3(prm.cam_right).normalize();
        let up = v3(prm.cam_up).normalize();
        let lens = o + right * (r * phi.cos()) + up * (r * phi.sin());
        o = lens;
        d = (focus - lens).normalize();
    }
    let mut time = prm.shutter_open;
    if plan.motion && prm.shutter_close > prm.shutter_open {
        time = prm.shutter_open + rnd(&mut seed) * (prm.shutter_close - prm.shutter_open);
    }
    PathRay {
        o: o.to_array(),
        tmin: 0.0,
        d: d.to_array(),
        tmax: FAR,
        weight: [1.0; 3],
        pixel,
        time,
        depth: 0,
        seed,
        kind: RAY_PRIMARY,
    }
}

fn move_vector(rs: &RenderScene, n: Vec3, prim: usize, time: f32) -> Vec3 {
    let g = &rs.geometry;
    let Some(&slot) = g.prim_motion.get(prim) else {
        return n;
    };
    if slot == NO_MOTION {
        return n;
    }
    let m = &g.motions[slot as usize];
    let angle = m.velocity[3] * time;
    if angle == 0.0 {
        return n;
    }
    let k = Vec3::from_slice(&m.axis[..3]);
    let (s, c) = angle.sin_cos();
    n * c + k.cross(n) * s + k * (k.dot(n) * (1.0 - c))
}

/// `shade.comp`'s `light_seen`: the emitted radiance of the nearest area light the ray meets
/// in (`tmin`, `tmax`) — a quad from its front side, a sphere from any — or `None`.
fn light_seen(
    lights: &[GpuLight],
    n_lights: u32,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<Vec3> {
    let mut nearest = tmax;
    let mut seen = None;
    for lt in &lights[..n_lights as usize] {
        let mut t = -1.0f32;
        if lt.kind[0] == LIGHT_QUAD {
            let (u, v) = (v3(lt.u), v3(lt.v));
            let n = u.cross(v);
            let dn = d.dot(n);
            if dn < 0.0 {
                t = (v3(lt.p) - o).dot(n) / dn;
                let q = o + t * d - v3(lt.p);
                let nn = n.dot(n);
                let a = q.cross(v).dot(n) / nn;
                let b = u.cross(q).dot(n) / nn;
                if !((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)) {
                    t = -1.0;
                }
            }
        } else if lt.kind[0] == LIGHT_SPHERE {
            let oc = o - v3(lt.p);
            let r = lt.u[3];
            let (qa, qb) = (d.dot(d), oc.dot(d));
            let disc = qb * qb - qa * (oc.dot(oc) - r * r);
            if disc >= 0.0 {
                let s = disc.sqrt();
                t = (-qb - s) / qa;
                if t <= tmin || t.is_nan() {
                    t = (-qb + s) / qa;
                }
            }
        }
        if t > tmin && t < nearest {
            nearest = t;
            seen = Some(v3(lt.power));
        }
    }
    seen
}

/// `shade.comp` for one ray.
fn shade(rs: &RenderScene, plan: &Plan, p: &PathRay, h: &Hit) -> Shaded {
    let prm = &rs.params;
    let slots = prm.shadow_slots as usize;
    let mut out = Shaded {
        radiance: Vec3::ZERO,
        shadows: vec![ShadowRay::default(); slots],
        children: [None, None],
    };
    let weight = Vec3::from_array(p.weight);
    let (o, d) = (Vec3::from_array(p.o), Vec3::from_array(p.d));
    // Glossy rays leave the lights to the Phong term of light sampling (no double count).
    if plan.area_lights && p.kind != RAY_GLOSSY {
        let tmax = if h.is_hit() { h.t } else { p.tmax };
        if let Some(le) = light_seen(&rs.lights, prm.n_lights, o, d, p.tmin, tmax) {
            out.radiance = weight * le;
            return out;
        }
    }
    if !h.is_hit() {
        out.radiance = weight * v3(prm.background);
        return out;
    }
    let g = &rs.geometry;
    let prim = h.prim as usize;
    let (x, mut ng, mut ns);
    if prim < g.triangle_count() {
        let [p0, p1, p2] = g.triangle_at(prim, p.time);
        let w = 1.0 - h.u - h.v;
        x = w * p0 + h.u * p1 + h.v * p2;
        ng = (p1 - p0).cross(p2 - p0).normalize();
        let nrm =
            |c: usize| Vec3::from_slice(&rs.tri_normals[9 * prim + 3 * c..9 * prim + 3 * c + 3]);
        let n = w * nrm(0) + h.u * nrm(1) + h.v * nrm(2);
        ns = if n.dot(n) > 0.0 {
            move_vector(rs, n, prim, p.time).normalize()
        } else {
            ng
        };
    } else if prim < g.triangle_count() + g.spheres.len() {
        let s: Vec4 = g.sphere_at(prim - g.triangle_count(), p.time);
        ng = (o + h.t * d - s.truncate()).normalize();
        x = s.truncate() + ng * s.w;
        ns = ng;
    } else {
        let b = &g.aabbs[prim - g.triangle_count() - g.spheres.len()];
        x = o + h.t * d;
        ng = crate::trace::intersect::aabb_normal(b.min, b.max, x);
        ns = ng;
    }
    let front = d.dot(ng) < 0.0;
    if !front {
        ng = -ng;
        ns = -ns;
    }
    if ns.dot(d) >= 0.0 {
        ns = ng;
    }
    let m = &rs.materials[rs.prim_material[prim] as usize];
    let diffuse = v3(m.diffuse);
    let mut l = Vec3::ZERO;
    if plan.emission {
        l += v3(m.emission);
    }
    let ao = plan.ambient_occlusion && prm.ao_samples > 0;
    if !ao {
        l += v3(prm.ambient) * diffuse;
    }
    out.radiance = weight * l;
    let mut rng = pcg(p.seed ^ 0xA511_E9B3);
    let o_front = offset_ray_origin(x, ng);
    if plan.lights {
        for (li, lt) in rs.lights.iter().enumerate() {
            let (wi, dist, e);
            let kind = lt.kind[0];
            if kind == LIGHT_DIRECTIONAL {
                wi = -v3(lt.p).normalize();
                dist = FAR;
                e = v3(lt.power);
            } else if kind == LIGHT_POINT || !plan.area_lights {
                let to = v3(lt.p) - x;
                dist = to.length();
                wi = to / dist;
                e = v3(lt.power) / (dist * dist);
            } else {
                let (q, nl, area);
                if kind == LIGHT_QUAD {
                    let r1 = rnd(&mut rng);
                    let r2 = rnd(&mut rng);
                    q = v3(lt.p) + r1 * v3(lt.u) + r2 * v3(lt.v);
                    let c = v3(lt.u).cross(v3(lt.v));
                    area = c.length();
                    nl = c / area;
                } else {
                    let mut n = sample_sphere(&mut rng);
                    if n.dot(x - v3(lt.p)) < 0.0 {
                        n = -n;
                    }
                    nl = n;
                    q = v3(lt.p) + n * lt.u[3];
                    area = 2.0 * PI * lt.u[3] * lt.u[3];
                }
                let to = q - x;
                dist = to.length();
                wi = to / dist;
                let cos_l = -nl.dot(wi);
                e = if cos_l > 0.0 {
                    v3(lt.power) * (cos_l * area / (dist * dist))
                } else {
                    Vec3::ZERO
                };
            }
            let cos_s = ns.dot(wi);
            if cos_s <= 0.0 || ng.dot(wi) <= 0.0 || e.max_element() <= 0.0 {
                continue;
            }
            let mut f = diffuse * cos_s;
            let spec = v3(m.specular);
            if spec.x + spec.y + spec.z > 0.0 {
                let rv = reflect_dir(-wi, ns).dot(-d).max(0.0);
                f += spec * rv.powf(m.diffuse[3]);
            }
            out.shadows[li] = ShadowRay {
                o: o_front.to_array(),
                tmin: 0.0,
                d: wi.to_array(),
                tmax: dist,
                contrib: (weight * f * e).to_array(),
                kind: SHADOW_LIGHT,
            };
        }
    }
    if ao {
        let c = weight * v3(prm.ambient) * diffuse / prm.ao_samples as f32;
        for k in 0..prm.ao_samples as usize {
            let dir = sample_cosine(ng, &mut rng);
            out.shadows[rs.lights.len() + k] = ShadowRay {
                o: o_front.to_array(),
                tmin: 0.0,
                d: dir.to_array(),
                tmax: prm.ao_radius,
                contrib: c.to_array(),
                kind: SHADOW_AO,
            };
        }
    }
    if !plan.bounces || p.depth >= prm.max_depth {
        return out;
    }
    let mut refl_w = v3(m.mirror);
    let mut trans = m.mirror[3];
    let mut tdir = Vec3::ZERO;
    let mut refracts = false;
    if plan.refraction && trans > 0.0 {
        let eta = if front {
            1.0 / m.emission[3]
        } else {
            m.emission[3]
        };
        let cos_i = -d.dot(ns);
        if let Some(t) = refract_dir(d, ns, eta) {
            tdir = t;
            refracts = t.dot(ng) < 0.0;
        }
        let fr = if refracts {
            if m.flags[0] != 0 {
                fresnel(cos_i, eta)
            } else {
                0.0
            }
        } else {
            1.0
        };
        refl_w += Vec3::splat(trans * fr);
        trans *= 1.0 - fr;
    }
    let rw = weight * refl_w;
    if (plan.reflection || plan.glossy) && rw.max_element() > prm.min_weight {
        let mut r = reflect_dir(d, ns);
        if r.dot(ng) <= 0.0 {
            r = reflect_dir(d, ng);
        }
        let mut kind = RAY_REFLECTION;
        if plan.glossy && m.specular[3] > 0.0 {
            let gl = sample_cone(r, m.specular[3], &mut rng);
            r = if gl.dot(ng) > 0.0 { gl } else { r };
            kind = RAY_GLOSSY;
        }
        out.children[0] = Some(PathRay {
            o: o_front.to_array(),
            tmin: 0.0,
            d: r.to_array(),
            tmax: FAR,
            weight: rw.to_array(),
            pixel: p.pixel,
            time: p.time,
            depth: p.depth + 1,
            seed: pcg(p.seed ^ 0x1B87_3593),
            kind,
        });
    }
    let tw = weight * trans;
    if plan.refraction && refracts && tw.max_element() > prm.min_weight {
        let mut t = tdir;
        if plan.glossy && m.specular[3] > 0.0 {
            let gl = sample_cone(t, m.specular[3], &mut rng);
            t = if gl.dot(ng) < 0.0 { gl } else { t };
        }
        out.children[1] = Some(PathRay {
            o: offset_ray_origin(x, -ng).to_array(),
            tmin: 0.0,
            d: t.to_array(),
            tmax: FAR,
            weight: tw.to_array(),
            pixel: p.pixel,
            time: p.time,
            depth: p.depth + 1,
            seed: pcg(p.seed ^ 0xCC9E_2D51),
            kind: RAY_REFRACTION,
        });
    }
    out
}
