//! Structures on the renderer's terms: geometry read from the caller's device buffers
//! (`accel.geometry_gather` against its CPU twin on every edge), built into memory the caller
//! allocates at the sizes vkrt reports (exact), the same trees as the host-soup path, updates
//! from moved vertices, and every misuse class answered with an `Err`.

mod common;

use glam::{Vec3, Vec4};
use vkrt::accel::device::{AccelBuilder, AccelKind, DevicePrimitives};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{
    gather_on_host, Aabbs, Geometry, GeometryData, GeometryGather, GeometryLayout, IndexType,
    Indices, Spheres, Transform, Triangles, VertexFormat,
};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::{
    Buffer, Context, CopiedStructure, DeviceRange, GpuError, PlacementProblem, RawBuffer, Recorder,
};
use vkrt::scene::Aabb;
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{cpu, Hit, Ray, TraceOptions};

/// The caller's memory, as bytes in vkrt buffers (any buffer with storage usage would do).
struct CallerBuffers {
    bufs: Vec<Buffer<u32>>,
    host: Vec<Vec<u8>>,
    /// The address handed out for each buffer by `at` (0: none).
    addresses: Vec<u64>,
}

impl CallerBuffers {
    fn new() -> Self {
        Self {
            bufs: Vec::new(),
            host: Vec::new(),
            addresses: Vec::new(),
        }
    }

    /// A buffer holding `pad` zero bytes then `bytes`, and the range of `bytes` in it.
    fn put(&mut self, ctx: &Context, bytes: &[u8], pad: usize) -> RawBuffer {
        let mut data = vec![0u8; pad];
        data.extend_from_slice(bytes);
        data.resize(data.len().next_multiple_of(4).max(4), 0);
        let b = Buffer::from_slice(ctx, "caller", bytemuck::cast_slice::<u8, u32>(&data)).unwrap();
        let raw = unsafe { RawBuffer::new(b.as_raw().buffer(), pad as u64, bytes.len() as u64) };
        self.bufs.push(b);
        self.host.push(bytes.to_vec());
        self.addresses.push(0);
        raw
    }

    /// The host copy of data handed out by `put` (or `at`).
    fn read(&self, d: &GeometryData) -> Vec<u8> {
        let k = match d {
            GeometryData::Buffer(r) => self
                .bufs
                .iter()
                .position(|b| unsafe { b.as_raw() }.buffer() == r.buffer()),
            GeometryData::Address { address, .. } => {
                self.addresses.iter().position(|a| a == address)
            }
            _ => None,
        }
        .expect("a caller buffer");
        self.host[k].clone()
    }

    /// [`CallerBuffers::put`], as data at a device address.
    fn at(&mut self, ctx: &Context, bytes: &[u8], pad: usize) -> GeometryData {
        let r = self.put(ctx, bytes, pad);
        let address = self.bufs.last().unwrap().device_address().unwrap() + r.offset();
        *self.addresses.last_mut().unwrap() = address;
        // SAFETY: the range of a buffer the test keeps until its builds have executed.
        unsafe { DeviceRange::new(address, r.size()) }.into()
    }
}

fn opt() -> TraceOptions {
    TraceOptions {
        exact: false,
        ..TraceOptions::default()
    }
}

/// A random indexed mesh: `n` triangles over `n + 2` vertices in [-1, 1]^3.
fn mesh(rng: &mut common::Rng, n: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let verts: Vec<Vec3> = (0..n + 2).map(|_| rng.next_vec3() * 2.0 - 1.0).collect();
    let v = verts.len() as u64;
    let tris = (0..n)
        .map(|_| [0, 1, 2].map(|_| (rng.next_u64() % v) as u32))
        .collect();
    (verts, tris)
}

/// Vertices at `stride` bytes (padding filled with a marker that must never be read).
fn strided(verts: &[Vec3], stride: usize) -> Vec<u8> {
    let mut out = vec![0xAB; verts.len() * stride];
    for (k, v) in verts.iter().enumerate() {
        out[k * stride..k * stride + 12].copy_from_slice(bytemuck::bytes_of(&v.to_array()));
    }
    out
}

/// Runs the gather on the device and reads back what it wrote.
fn gather_on_device(ctx: &Context, geometries: &[Geometry]) -> (TraceGeometry, u32) {
    let layout = GeometryLayout::of(ctx, geometries).unwrap();
    let prims = DevicePrimitives::for_layout(ctx, &layout).unwrap();
    let info = Buffer::new(ctx, "info", layout.info_len()).unwrap();
    let gather = GeometryGather::new(ctx).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    gather
        .record(&mut rec, geometries, &layout, &prims, &info, 1, 0)
        .unwrap();
    rec.submit_and_wait().unwrap();
    let n_tris = layout.n_tris as usize;
    let mut tri_verts = prims.tri_verts.download().unwrap();
    tri_verts.truncate(9 * n_tris);
    let boxes = prims.boxes.download().unwrap();
    let info = info.download().unwrap();
    // The spheres, then two words per box primitive.
    let mut spheres = prims.spheres.download().unwrap();
    let aabbs = spheres
        .split_off(layout.n_spheres as usize)
        .chunks(2)
        .map(|w| Aabb {
            min: Vec4::from_array(w[0]).truncate(),
            max: Vec4::from_array(w[1]).truncate(),
        })
        .collect();
    let g = TraceGeometry {
        tri_verts,
        spheres,
        aabbs,
        boxes: boxes
            .chunks(6)
            .map(|b| vkrt::scene::Aabb {
                min: Vec3::new(b[0], b[1], b[2]),
                max: Vec3::new(b[3], b[4], b[5]),
            })
            .collect(),
        ..TraceGeometry::default()
    };
    assert_eq!(info[0].n_tris, layout.n_tris);
    assert_eq!(info[0].n_spheres, layout.n_spheres);
    assert_eq!(info[0].n_aabbs, layout.n_aabbs);
    assert_eq!(info[0].n_geometries as usize, layout.table.len());
    // The table the walk searches, ordered by first id.
    let words: &[u32] = bytemuck::cast_slice(&info);
    let table: Vec<[u32; 2]> = words[16..16 + 2 * layout.table.len()]
        .chunks(2)
        .map(|w| [w[0], w[1]])
        .collect();
    assert_eq!(table, layout.table);
    (g, info[0].invalid)
}

type Bits = (Vec<u32>, Vec<[u32; 4]>, Vec<[u32; 6]>, Vec<[u32; 6]>);

fn bits(g: &TraceGeometry) -> Bits {
    let box_bits =
        |b: &Aabb| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits);
    (
        g.tri_verts.iter().map(|x| x.to_bits()).collect(),
        g.spheres.iter().map(|s| s.map(f32::to_bits)).collect(),
        g.aabbs.iter().map(box_bits).collect(),
        g.boxes.iter().map(box_bits).collect(),
    )
}

/// `n` random boxes (some flat, one inactive: min > max) as the caller's bytes at `stride`.
fn random_aabbs(rng: &mut common::Rng, n: usize, stride: usize) -> Vec<u8> {
    let mut out = vec![0xCD; n * stride];
    for k in 0..n {
        let lo = rng.next_vec3() * 1.2;
        let mut size = (rng.next_vec3() + 1.0) * 0.15;
        if k % 7 == 3 {
            size.y = 0.0;
        }
        if k % 11 == 5 {
            size.x = -0.1;
        }
        let b = [lo, lo + size].map(|v| v.to_array());
        out[k * stride..k * stride + 24].copy_from_slice(bytemuck::cast_slice(&b));
    }
    out
}

#[test]
fn the_gather_equals_its_cpu_twin_on_every_edge() {
    let Some(ctx) = common::context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let mut rng = common::Rng(11);
    let sizes = common::edge_sizes(sg, 64, 64)
        .into_iter()
        .filter(|&n| n < 1 << 16);
    for n in sizes.chain([1000, 100_003]) {
        let bda = ctx.info().features.buffer_device_address;
        for (stride, pad, index, address) in [
            (12, 0, Some(IndexType::U32), false),
            (16, 4, Some(IndexType::U16), false),
            (20, 8, None, false),
            (12, 4, Some(IndexType::U16), bda),
            (16, 0, Some(IndexType::U32), bda),
        ] {
            // Data at a device address (where the device has bufferDeviceAddress), else in
            // a bound range.
            let place = |caller: &mut CallerBuffers, bytes: &[u8], pad: usize| -> GeometryData {
                match address {
                    true => caller.at(&ctx, bytes, pad),
                    false => caller.put(&ctx, bytes, pad).into(),
                }
            };
            let (verts, tris) = mesh(&mut rng, n);
            let mut caller = CallerBuffers::new();
            let (vertex_count, indices, vbytes) = match index {
                None => {
                    // A soup: the triangles' corners in order.
                    let soup: Vec<Vec3> =
                        tris.iter().flatten().map(|&i| verts[i as usize]).collect();
                    (soup.len() as u32, None, strided(&soup, stride))
                }
                Some(t) => {
                    let flat: Vec<u32> = tris.iter().flatten().copied().collect();
                    let bytes: Vec<u8> = match t {
                        IndexType::U16 => bytemuck::cast_slice(
                            &flat.iter().map(|&i| i as u16).collect::<Vec<u16>>(),
                        )
                        .to_vec(),
                        _ => bytemuck::cast_slice(&flat).to_vec(),
                    };
                    let data = place(&mut caller, &bytes, if t == IndexType::U16 { 2 } else { 4 });
                    (
                        verts.len() as u32,
                        Some(Indices {
                            data,
                            index_type: t,
                        }),
                        strided(&verts, stride),
                    )
                }
            };
            let vertices = place(&mut caller, &vbytes, pad);
            // Given by the host, or (at addresses) read by the build where it lies.
            let rows = [
                [0.5, 0.1, 0.0, 1.0],
                [0.0, 1.5, 0.2, -2.0],
                [0.3, 0.0, 1.0, 0.25],
            ];
            let transform = (stride == 16).then(|| match address {
                true => match caller.at(&ctx, bytemuck::cast_slice(&rows), 0) {
                    // SAFETY: as in `at`.
                    GeometryData::Address { address: at, .. } => {
                        Transform::at(unsafe { DeviceRange::new(at, 48) })
                    }
                    _ => unreachable!("data at an address"),
                },
                false => Transform::Rows(rows),
            });
            let spheres: Vec<Vec4> = (0..n % 5 + 1)
                .map(|_| (rng.next_vec3() * 2.0 - 1.0).extend(rng.next_f32()))
                .collect();
            let sphere_range = place(&mut caller, bytemuck::cast_slice(&spheres), 0);
            let n_boxes = (n * 7) % 300;
            let box_stride = [24, 28, 32][n % 3];
            let box_bytes = random_aabbs(&mut rng, n_boxes, box_stride);
            let box_range = place(&mut caller, &box_bytes, pad);
            let geometries = [
                Geometry::Aabbs(Aabbs {
                    data: box_range,
                    stride: box_stride as u64,
                    count: n_boxes as u32,
                    opaque: true,
                }),
                Geometry::Spheres(Spheres {
                    data: sphere_range,
                    stride: 16,
                    count: spheres.len() as u32,
                    opaque: true,
                }),
                Geometry::Triangles(Triangles {
                    vertices,
                    stride: stride as u64,
                    vertex_count,
                    indices,
                    triangle_count: n as u32,
                    transform,
                    ..Triangles::soup(vertices, vertex_count)
                }),
            ];
            let (device, invalid) = gather_on_device(&ctx, &geometries);
            let (host, host_invalid) = gather_on_host(&geometries, |r| caller.read(r));
            assert_eq!(invalid, host_invalid, "n {n} stride {stride}");
            assert_eq!(
                bits(&device),
                bits(&host),
                "n {n} stride {stride} {index:?}"
            );
        }
    }
    common::assert_silent(&ctx);
}

/// Every vertex format the extension requires, read from random bits (halves of every
/// kind: subnormals, infinities and NaNs among them; snorms down to -32768; 32-bit floats
/// but their subnormals), in a bound
/// range and at a device address, with strides at and above a vertex: the gather equals its
/// CPU twin bit for bit, invalid triangles counted alike.
#[test]
fn every_vertex_format_is_gathered_as_its_cpu_twin_reads_it() {
    let Some(ctx) = common::context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let bda = ctx.info().features.buffer_device_address;
    let mut rng = common::Rng(29);
    let formats = [
        VertexFormat::Rgb32Float,
        VertexFormat::Rg32Float,
        VertexFormat::Rg16Float,
        VertexFormat::Rgba16Float,
        VertexFormat::Rg16Snorm,
        VertexFormat::Rgba16Snorm,
    ];
    for n in [1, sg - 1, sg, 65, 1000] {
        for (f, format) in formats.into_iter().enumerate() {
            for address in [false, bda] {
                let stride = format.bytes() + 4 * (n as u64 % 2);
                let vertex_count = n as u32 + 2;
                let mut caller = CallerBuffers::new();
                // Random bits; a 32-bit float's subnormals become zeros, since a device may
                // flush them (the specification allows it; Mesa 26.1's lavapipe does).
                let vbytes: Vec<u8> = (0..vertex_count as u64 * stride / 4)
                    .flat_map(|_| {
                        let w = rng.next_u64() as u32;
                        let w = match (f < 2, w & 0x7f80_0000) {
                            (true, 0) => w & 0x8000_0000,
                            _ => w,
                        };
                        w.to_le_bytes()
                    })
                    .collect();
                let flat: Vec<u32> = (0..3 * n)
                    .map(|_| (rng.next_u64() % u64::from(vertex_count)) as u32)
                    .collect();
                let place = |caller: &mut CallerBuffers, bytes: &[u8]| -> GeometryData {
                    match address {
                        true => caller.at(&ctx, bytes, 0),
                        false => caller.put(&ctx, bytes, 0).into(),
                    }
                };
                let indices = place(&mut caller, bytemuck::cast_slice(&flat));
                let vertices = place(&mut caller, &vbytes);
                let geometries = [Geometry::Triangles(Triangles {
                    format,
                    stride,
                    indices: Some(Indices {
                        data: indices,
                        index_type: IndexType::U32,
                    }),
                    triangle_count: n as u32,
                    ..Triangles::soup(vertices, vertex_count)
                })];
                let (device, invalid) = gather_on_device(&ctx, &geometries);
                let (host, host_invalid) = gather_on_host(&geometries, |r| caller.read(r));
                let what = format!("n {n} {format:?} stride {stride} at an address {address}");
                assert_eq!(invalid, host_invalid, "{what}");
                assert_eq!(bits(&device), bits(&host), "{what}");
                // Half and snorm formats see valid triangles too, where there are enough
                // for chance (f 0 and 1: 32-bit random bits are mostly huge or NaN).
                if f >= 2 && n >= 65 {
                    assert!(host_invalid < n as u32, "{what}: every triangle invalid");
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn bad_indices_and_coordinates_become_unhittable_points_and_are_counted() {
    let Some(ctx) = common::context() else { return };
    let mut caller = CallerBuffers::new();
    let verts = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(f32::NAN, 0.0, 0.0)];
    let vertices = caller.put(&ctx, bytemuck::cast_slice(&verts), 0);
    let idx: [u32; 9] = [0, 1, 2, 0, 1, 99, 0, 1, 3];
    let data = caller.put(&ctx, bytemuck::cast_slice(&idx), 0);
    let spheres = [
        Vec4::new(0.0, 0.0, 0.0, -1.0),
        Vec4::new(1.0, 1.0, 1.0, 0.5),
    ];
    let sph = caller.put(&ctx, bytemuck::cast_slice(&spheres), 0);
    // A good box, one with a NaN, one with an infinite bound, and an inactive one (min > max:
    // not invalid, as in Vulkan).
    let boxes: [[f32; 6]; 4] = [
        [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
        [0.0, f32::NAN, 0.0, 1.0, 1.0, 1.0],
        [0.0, 0.0, 0.0, 1.0, f32::INFINITY, 1.0],
        [2.0, 0.0, 0.0, 1.0, 1.0, 1.0],
    ];
    let bx = caller.put(&ctx, bytemuck::cast_slice(&boxes), 0);
    let geometries = [
        Geometry::Triangles(Triangles::indexed(vertices, 4, data, IndexType::U32, 3)),
        Geometry::Spheres(Spheres {
            data: sph.into(),
            stride: 16,
            count: 2,
            opaque: true,
        }),
        Geometry::Aabbs(Aabbs {
            data: bx.into(),
            stride: 24,
            count: 4,
            opaque: true,
        }),
    ];
    let (device, invalid) = gather_on_device(&ctx, &geometries);
    let (host, host_invalid) = gather_on_host(&geometries, |r| caller.read(r));
    assert_eq!((invalid, host_invalid), (5, 5));
    // No ray hits an invalid or inactive box; the good one is hit.
    let r = Ray::new(Vec3::new(0.9, 0.9, -5.0), Vec3::Z, 0.0, f32::INFINITY);
    let h = cpu::brute_force(&host, &r, 0.0, &opt());
    assert_eq!((h.prim, h.t), (3 + 2, 5.0));
    for b in &host.aabbs[1..] {
        assert!(!b.min.cmple(b.max).all(), "{b:?} is inactive");
    }
    assert_eq!(bits(&device), bits(&host));
    common::assert_silent(&ctx);
}

/// Triangles of `tris` (a soup) in a caller buffer, as one geometry.
fn soup_geometry(ctx: &Context, caller: &mut CallerBuffers, tris: &[[Vec3; 3]]) -> Geometry {
    let flat: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let vertices = caller.put(ctx, bytemuck::cast_slice(&flat), 0);
    Geometry::Triangles(Triangles::soup(vertices, flat.len() as u32))
}

/// Builds `kind` over `geometries` in caller memory of exactly the reported sizes.
fn build_in_caller_memory(
    ctx: &Context,
    builder: &AccelBuilder,
    geometries: &[Geometry],
    flags: &BuildFlags,
) -> (GpuGeometry, Vec<Buffer<u8>>) {
    let sizes = builder.sizes_for(ctx, geometries, flags).unwrap();
    let structure =
        Buffer::<u8>::arena(ctx, "caller.structure", sizes.structure_bytes as usize).unwrap();
    let scratch =
        Buffer::<u8>::arena(ctx, "caller.scratch", sizes.build_scratch_bytes as usize).unwrap();
    let mut g = builder
        .create_in(ctx, geometries, flags, unsafe { structure.as_raw() })
        .unwrap();
    let before = ctx.traffic();
    let mut rec = Recorder::new(ctx).unwrap();
    builder
        .record_build_from(&mut rec, &mut g, geometries, unsafe { scratch.as_raw() })
        .unwrap();
    let recorded = ctx.traffic() - before;
    // Every kind, the driver's too: its levels, instance records and scratch lie in the
    // caller's ranges; the records and the top level's address are constants written by
    // the command buffer itself (vkCmdUpdateBuffer), not staged uploads.
    assert_eq!(
        recorded.upload_bytes,
        0,
        "{:?}: bytes uploaded",
        builder.kind()
    );
    assert_eq!(
        recorded.device_allocations,
        0,
        "{:?}: buffers",
        builder.kind()
    );
    match builder.kind() {
        AccelKind::Driver => assert!(recorded.inline_bytes > 0 && recorded.inline_bytes <= 160),
        _ => assert_eq!(recorded.inline_bytes, 0),
    }
    assert_eq!(recorded.submits, 0);
    rec.submit_and_wait().unwrap();
    (g, vec![structure, scratch])
}

fn trace(ctx: &Context, kind: AccelKind, g: &GpuGeometry, rays: &[Ray]) -> Vec<Hit> {
    let tracer = Tracer::for_accel(ctx, &opt(), kind.walked(Default::default())).unwrap();
    let b = tracer.trace(ctx, g, rays, 0.0).unwrap();
    assert_eq!(b.exhausted, 0);
    b.hits
}

fn rays_into(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = common::Rng(seed);
    let (lo, hi) = tris.iter().flatten().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length().max(1e-3);
    (0..n)
        .map(|_| {
            let o = c + (rng.next_vec3() * 2.0 - 1.0).normalize_or(Vec3::X) * r;
            let t = c + (rng.next_vec3() - 0.5) * r * 0.5;
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect()
}

#[test]
fn builds_from_device_buffers_equal_the_host_soup_path_and_brute_force() {
    let Some(ctx) = common::context() else { return };
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let rays = rays_into(&tris, 500, 3);
    let soup = TraceGeometry::from_triangles(&tris);
    let brute: Vec<Hit> = rays
        .iter()
        .map(|r| cpu::brute_force(&soup, r, 0.0, &opt()))
        .collect();
    let mut kinds = vec![AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc];
    if ctx.info().features.ray_query {
        kinds.push(AccelKind::Driver);
    }
    for kind in kinds {
        for n in [0usize, 1, 2, tris.len()] {
            let mut caller = CallerBuffers::new();
            let geometries = [soup_geometry(&ctx, &mut caller, &tris[..n])];
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let (g, _mem) =
                build_in_caller_memory(&ctx, &builder, &geometries, &BuildFlags::default());
            let hits = trace(&ctx, kind, &g, &rays);
            let part = TraceGeometry::from_triangles(&tris[..n]);
            for (k, (r, h)) in rays.iter().zip(&hits).enumerate() {
                let b = if n == tris.len() {
                    brute[k]
                } else {
                    cpu::brute_force(&part, r, 0.0, &opt())
                };
                assert!(common::same_answer(h, &b), "{kind:?} n {n}: {h:?} vs {b:?}");
            }
            // vkrt's own builders: the same tree as from the host's soup, bit for bit.
            if kind != AccelKind::Driver && n > 0 {
                let mut rec = Recorder::new(&ctx).unwrap();
                let (host, _) = GpuGeometry::record_build(&mut rec, &builder, &part, 0).unwrap();
                rec.submit_and_wait().unwrap();
                assert_eq!(
                    g.structure().download().unwrap(),
                    host.structure().download().unwrap(),
                    "{kind:?} n {n}"
                );
            }
        }
    }
    common::assert_silent(&ctx);
}

/// Triangles, spheres and boxes (flat and inactive ones among them) in caller buffers, and
/// the same primitives as the CPU twin holds them.
fn mixed_scene(ctx: &Context, caller: &mut CallerBuffers) -> (Vec<Geometry>, TraceGeometry) {
    let mut rng = common::Rng(21);
    // A small icosphere among the spheres and boxes, so that rays reach all three.
    let tris: Vec<[Vec3; 3]> = common::mesh_triangles(&vkrt::scene::gen::icosphere(2).unwrap())
        .iter()
        .map(|t| t.map(|p| p * 0.4))
        .collect();
    let spheres: Vec<Vec4> = (0..20)
        .map(|_| (rng.next_vec3() * 1.2).extend(0.15 + 0.1 * rng.next_f32()))
        .collect();
    let box_bytes = random_aabbs(&mut rng, 60, 32);
    let geometries = vec![
        Geometry::Aabbs(Aabbs {
            data: caller.put(ctx, &box_bytes, 8).into(),
            stride: 32,
            count: 60,
            opaque: true,
        }),
        soup_geometry(ctx, caller, &tris),
        Geometry::Spheres(Spheres {
            data: caller.put(ctx, bytemuck::cast_slice(&spheres), 0).into(),
            stride: 16,
            count: spheres.len() as u32,
            opaque: true,
        }),
    ];
    let (host, invalid) = gather_on_host(&geometries, |r| caller.read(r));
    assert_eq!(invalid, 0);
    (geometries, host)
}

#[test]
fn box_primitives_are_traced_by_every_kind_and_walk_as_brute_force() {
    let Some(ctx) = common::context() else { return };
    let mut caller = CallerBuffers::new();
    let (geometries, host) = mixed_scene(&ctx, &mut caller);
    let layout = GeometryLayout::of(&ctx, &geometries).unwrap();
    assert_eq!(
        (layout.n_tris, layout.n_spheres, layout.n_aabbs),
        (320, 20, 60)
    );
    // Rays from around the scene through it, at every box's centre and sphere's centre,
    // and from inside boxes.
    let mut rng = common::Rng(5);
    let mut rays = Vec::new();
    let mut towards = |target: Vec3, rng: &mut common::Rng| {
        let o = rng.next_vec3().normalize_or(Vec3::X) * 4.0;
        rays.push(Ray::new(o, target - o, 0.0, f32::INFINITY));
    };
    for _ in 0..300 {
        let t = rng.next_vec3() * 1.3;
        towards(t, &mut rng);
    }
    for b in &host.aabbs {
        towards((b.min + b.max) * 0.5, &mut rng);
    }
    for s in &host.spheres {
        towards(Vec4::from_array(*s).truncate(), &mut rng);
    }
    for b in host
        .aabbs
        .iter()
        .filter(|b| b.min.cmplt(b.max).all())
        .take(20)
    {
        rays.push(Ray::new(
            (b.min + b.max) * 0.5,
            Vec3::new(0.3, -1.0, 0.2),
            0.0,
            f32::INFINITY,
        ));
    }
    let brute: Vec<Hit> = rays
        .iter()
        .map(|r| cpu::brute_force(&host, r, 0.0, &opt()))
        .collect();
    let first_box = layout.n_tris + layout.n_spheres;
    let box_hits = brute
        .iter()
        .filter(|h| h.is_hit() && h.prim >= first_box)
        .count();
    let sphere_hits = brute
        .iter()
        .filter(|h| h.is_hit() && h.prim >= layout.n_tris && h.prim < first_box)
        .count();
    assert!(
        box_hits > 60 && sphere_hits > 20,
        "{box_hits} box hits, {sphere_hits} sphere hits"
    );
    let mut kinds = vec![AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc];
    if ctx.info().features.ray_query {
        kinds.push(AccelKind::Driver);
    }
    let check = |label: &str, hits: &[Hit]| {
        for (k, (h, b)) in hits.iter().zip(&brute).enumerate() {
            assert!(common::same_answer(h, b), "{label} ray {k}: {h:?} vs {b:?}");
        }
    };
    for kind in kinds {
        let walks: &[Traversal] = match kind {
            AccelKind::Lbvh | AccelKind::Ploc => &Traversal::ALL,
            _ => &[Traversal::Stack],
        };
        for &walk in walks {
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let flags = BuildFlags {
                wide: walk == Traversal::Wide,
                ..BuildFlags::default()
            };
            let (g, _mem) = build_in_caller_memory(&ctx, &builder, &geometries, &flags);
            let tracer = Tracer::for_accel(&ctx, &opt(), kind.walked(walk)).unwrap();
            let b = tracer.trace(&ctx, &g, &rays, 0.0).unwrap();
            assert_eq!(b.exhausted, 0);
            check(&format!("{kind:?} {walk:?} from device buffers"), &b.hits);
        }
    }
    // The host path: the CPU twin's arrays uploaded, every kind including the SAH BVH.
    for kind in AccelKind::available(&ctx) {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let (g, _) = GpuGeometry::record_build(&mut rec, &builder, &host, 0).unwrap();
        rec.submit_and_wait().unwrap();
        let tracer = Tracer::for_accel(&ctx, &opt(), kind.walked(Traversal::Stack)).unwrap();
        let b = tracer.trace(&ctx, &g, &rays, 0.0).unwrap();
        check(&format!("{kind:?} from the host"), &b.hits);
    }
    common::assert_silent(&ctx);
}

#[test]
fn a_shader_s_own_box_intersection_is_called_with_its_indices() {
    let Some(ctx) = common::context() else { return };
    let mut caller = CallerBuffers::new();
    let (mut geometries, host) = mixed_scene(&ctx, &mut caller);
    // Boxes and triangles only (spheres appear as the boxes' inscribed ones), the boxes in
    // two geometries around the triangles.
    geometries.pop();
    let half = host.aabbs.len() / 2;
    let tail = random_aabbs(&mut common::Rng(8), half, 24);
    geometries.push(Geometry::Aabbs(Aabbs {
        data: caller.put(&ctx, &tail, 0).into(),
        stride: 24,
        count: half as u32,
        opaque: true,
    }));
    let layout = GeometryLayout::of(&ctx, &geometries).unwrap();
    let (boxes_host, _) = gather_on_host(&geometries, |r| caller.read(r));
    // The CPU twin: each box's inscribed sphere, as the probe's intersection makes it (none
    // for an inactive box: the walk never asks the shader about one).
    let inscribed: Vec<Vec4> = boxes_host
        .aabbs
        .iter()
        .map(|b| {
            if !b.min.cmple(b.max).all() {
                return Vec4::NAN;
            }
            let c = (b.min + b.max) * 0.5;
            let e = b.max - b.min;
            c.extend(0.5 * e.x.min(e.y).min(e.z))
        })
        .collect();
    let tris: Vec<[Vec3; 3]> = (0..boxes_host.triangle_count())
        .map(|k| boxes_host.triangle_at(k, 0.0))
        .collect();
    let twin = TraceGeometry::from_triangles_and_spheres(&tris, &inscribed);
    let mut rng = common::Rng(9);
    let mut targets: Vec<Vec3> = inscribed
        .iter()
        .filter(|s| s.is_finite())
        .map(|s| s.truncate())
        .collect();
    targets.extend((0..200).map(|_| rng.next_vec3() * 1.3));
    let rays: Vec<Ray> = targets
        .into_iter()
        .map(|t| {
            let o = rng.next_vec3().normalize_or(Vec3::X) * 4.0;
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect();
    let kernel = ctx
        .kernel(
            &vkrt::gpu::kernels::GPU_PROCEDURAL_PROBE,
            &vkrt::gpu::Spec::new().workgroup(64),
        )
        .unwrap();
    let ray_buf = Buffer::from_slice(&ctx, "probe.rays", &rays).unwrap();
    let mut box_hits = 0;
    for kind in [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc] {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let (g, _mem) = build_in_caller_memory(&ctx, &builder, &geometries, &BuildFlags::default());
        let out = Buffer::<[u32; 4]>::zeroed(&ctx, "probe.hits", rays.len()).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let [b0, b1, b2, b3, b4, b5, b6] = g.bindings();
        let groups = rec.groups_1d(rays.len() as u64, 64);
        rec.dispatch(
            &kernel,
            groups,
            &[&ray_buf, &out, b0, b1, b2, b3, b4, b5, b6],
            &(rays.len() as u32),
        );
        rec.compute_to_transfer();
        rec.submit_and_wait().unwrap();
        for (k, (r, got)) in rays.iter().zip(out.download().unwrap()).enumerate() {
            let want = cpu::brute_force(&twin, r, 0.0, &opt());
            assert_ne!(got[0], 0xffff_fffe, "{kind:?} ray {k} exhausted");
            assert_eq!(
                got[0] != u32::MAX,
                want.is_hit(),
                "{kind:?} ray {k}: {got:?} vs {want:?}"
            );
            if !want.is_hit() {
                continue;
            }
            let h = Hit {
                t: f32::from_bits(got[0]),
                prim: want.prim,
                ..want
            };
            assert!(
                common::same_answer(&h, &want),
                "{kind:?} ray {k}: {got:?} vs {want:?}"
            );
            // The twin's ids are vkrt's: triangles, then the boxes of both geometries.
            let (geometry, primitive) = layout.locate(want.prim).unwrap();
            assert_eq!([got[1], got[2]], [geometry, primitive], "{kind:?} ray {k}");
            if want.prim >= layout.n_tris {
                box_hits += 1;
                // The intersection got the same indices as the walk reports.
                assert_eq!(got[3], geometry | (primitive << 16), "{kind:?} ray {k}");
            }
        }
    }
    assert!(box_hits > 90, "{box_hits} hits on boxes");
    common::assert_silent(&ctx);
}

/// How `gpu.handle_probe` reaches the structure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Probe {
    /// Seven storage buffers.
    Set,
    /// The first three as texel buffers (`VKRT_TEXEL_BUFFERS`).
    Texel,
    /// Its handle's device addresses.
    Address,
}

/// Closest hits of `rays` through `vkrt/ray_query.glsl` from `gpu.handle_probe`, reaching
/// the structure as `how` says.
pub fn probe_hits(ctx: &Context, g: &GpuGeometry, rays: &[Ray], how: Probe) -> Vec<[u32; 4]> {
    let address = how == Probe::Address;
    let blob = match how {
        Probe::Address => &vkrt::gpu::kernels::GPU_HANDLE_PROBE_ADDRESS,
        Probe::Texel => &vkrt::gpu::kernels::GPU_HANDLE_PROBE_TEXEL,
        Probe::Set => &vkrt::gpu::kernels::GPU_HANDLE_PROBE_SET,
    };
    let kernel = ctx
        .kernel(blob, &vkrt::gpu::Spec::new().workgroup(64))
        .unwrap();
    let ray_buf = Buffer::from_slice(ctx, "probe.rays", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "probe.hits", rays.len()).unwrap();
    let handle = match address {
        true => Some(Buffer::from_slice(ctx, "probe.handle", &g.handle_words().unwrap()).unwrap()),
        false => None,
    };
    let at = handle.as_ref().map_or(0, |h| h.device_address().unwrap());
    let push = [rays.len() as u32, 0, at as u32, (at >> 32) as u32, 0, 0];
    let mut rec = Recorder::new(ctx).unwrap();
    let [b0, b1, b2, b3, b4, b5, b6] = g.bindings();
    let groups = rec.groups_1d(rays.len() as u64, 64);
    let all: [&dyn vkrt::gpu::BufferArg; 9] = [&ray_buf, &out, b0, b1, b2, b3, b4, b5, b6];
    // The address variant binds only its rays and hits.
    let bound = if address { &all[..2] } else { &all[..] };
    rec.dispatch(&kernel, groups, bound, &push);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    out.download().unwrap()
}

/// Through `vkrt/ray_query.glsl` as storage buffers, texel buffers and device addresses:
/// the same hits bit for bit, every kind and BVH walk (wide nodes included), and brute
/// force's.
#[test]
fn the_structure_s_bindings_texel_views_and_handle_give_the_same_hits() {
    let Some(ctx) = common::context() else { return };
    let addresses = ctx.info().features.buffer_device_address;
    if !addresses {
        eprintln!("no bufferDeviceAddress: the address variant is left out");
    }
    let mut caller = CallerBuffers::new();
    let (geometries, host) = mixed_scene(&ctx, &mut caller);
    let layout = GeometryLayout::of(&ctx, &geometries).unwrap();
    let mut rng = common::Rng(17);
    let rays: Vec<Ray> = (0..500)
        .map(|_| {
            let o = rng.next_vec3().normalize_or(Vec3::X) * 4.0;
            Ray::new(o, rng.next_vec3() * 1.3 - o, 0.0, f32::INFINITY)
        })
        .collect();
    let choices = [
        (AccelKind::KdTree, false),
        (AccelKind::Lbvh, false),
        (AccelKind::Lbvh, true),
        (AccelKind::Ploc, false),
        (AccelKind::Ploc, true),
    ];
    for (kind, wide) in choices {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let flags = BuildFlags {
            wide,
            ..BuildFlags::default()
        };
        let (g, _mem) = build_in_caller_memory(&ctx, &builder, &geometries, &flags);
        let set = probe_hits(&ctx, &g, &rays, Probe::Set);
        let texel = probe_hits(&ctx, &g, &rays, Probe::Texel);
        assert_eq!(set, texel, "{kind:?} (wide: {wide}): texel buffers");
        if addresses {
            let address = probe_hits(&ctx, &g, &rays, Probe::Address);
            assert_eq!(set, address, "{kind:?} (wide: {wide}): addresses");
        }
        assert!(
            set.iter().all(|h| h[0] != 0xffff_fffe),
            "{kind:?}: exhausted"
        );
        for (k, (r, got)) in rays.iter().zip(&set).enumerate() {
            let want = cpu::brute_force(&host, r, 0.0, &opt());
            assert_eq!(got[0] != u32::MAX, want.is_hit(), "{kind:?} ray {k}");
            if want.is_hit() {
                let h = Hit {
                    t: f32::from_bits(got[0]),
                    ..want
                };
                assert!(common::same_answer(&h, &want), "{kind:?} ray {k}");
                let (geometry, primitive) = layout.locate(want.prim).unwrap();
                assert_eq!([got[1], got[2]], [geometry, primitive], "{kind:?} ray {k}");
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn sizes_are_exact_and_too_little_memory_is_an_error() {
    let Some(ctx) = common::context() else { return };
    let sphere = vkrt::scene::gen::icosphere(2).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let mut caller = CallerBuffers::new();
    let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
    let mut kinds = vec![AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc];
    if ctx.info().features.ray_query {
        kinds.push(AccelKind::Driver);
    }
    for kind in kinds {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let flags = BuildFlags {
            allow_update: kind != AccelKind::KdTree,
            ..BuildFlags::default()
        };
        let s = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
        assert!(
            s.structure_bytes > 0 && s.build_scratch_bytes > 0,
            "{kind:?} {s:?}"
        );
        assert_eq!(s.update_scratch_bytes.is_some(), kind != AccelKind::KdTree);
        // A range 4 bytes short (buffers themselves hold whole 16-byte texels).
        let short = |b: &Buffer<u8>, bytes: u64| unsafe {
            RawBuffer::new(b.as_raw().buffer(), b.as_raw().offset(), bytes - 4)
        };
        let exact = Buffer::<u8>::arena(&ctx, "exact", s.structure_bytes as usize).unwrap();
        let err = builder
            .create_in(&ctx, &geometries, &flags, short(&exact, s.structure_bytes))
            .err()
            .expect("a structure in too little memory");
        // The numbers to branch on, not only prose: what the range holds and what it needs.
        match err {
            GpuError::Placement {
                problem: PlacementProblem::TooSmall { needed, given },
                ..
            } => assert_eq!((needed, given), (s.structure_bytes, s.structure_bytes - 4)),
            e => panic!("{e}"),
        }
        // An offset off the device's placement alignment is refused, naming that alignment.
        let align = AccelBuilder::placement_alignment(&ctx);
        assert!(
            align.is_power_of_two() && (4..=256).contains(&align),
            "{align}"
        );
        let roomy =
            Buffer::<u8>::arena(&ctx, "roomy", (s.structure_bytes + align) as usize).unwrap();
        // SAFETY: the test's buffer, alive until the end of the loop; nothing is recorded.
        let off = unsafe { RawBuffer::new(roomy.as_raw().buffer(), align / 2, s.structure_bytes) };
        match builder.create_in(&ctx, &geometries, &flags, off).err() {
            Some(GpuError::Placement {
                problem: PlacementProblem::Misaligned { offset, alignment },
                ..
            }) => assert_eq!((offset, alignment), (align / 2, align)),
            other => panic!("{other:?}"),
        }
        let mut g = builder
            .create_in(&ctx, &geometries, &flags, unsafe { exact.as_raw() })
            .unwrap();
        let scratch = Buffer::<u8>::arena(&ctx, "scratch", s.build_scratch_bytes as usize).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let err = builder
            .record_build_from(
                &mut rec,
                &mut g,
                &geometries,
                short(&scratch, s.build_scratch_bytes),
            )
            .expect_err("a build with too little scratch");
        assert!(matches!(err, GpuError::Placement { .. }), "{err}");
        drop(rec);
    }
    common::assert_silent(&ctx);
}

#[test]
fn an_update_reads_moved_vertices_from_the_callers_buffer() {
    let Some(ctx) = common::context() else { return };
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let moved: Vec<[Vec3; 3]> = tris
        .iter()
        .map(|t| t.map(|p| p * 1.3 + Vec3::new(0.2, -0.1, 0.05)))
        .collect();
    let rays = rays_into(&moved, 400, 5);
    let mut kinds = vec![AccelKind::Lbvh, AccelKind::Ploc];
    if ctx.info().features.ray_query {
        kinds.push(AccelKind::Driver);
    }
    for kind in kinds {
        let mut caller = CallerBuffers::new();
        let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let flags = BuildFlags {
            allow_update: true,
            ..BuildFlags::default()
        };
        let (mut g, _mem) = build_in_caller_memory(&ctx, &builder, &geometries, &flags);
        // The caller moves its vertices, where they lie.
        let flat: Vec<Vec3> = moved.iter().flatten().copied().collect();
        caller.bufs[0].upload(bytemuck::cast_slice(&flat)).unwrap();
        let s = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
        let scratch =
            Buffer::<u8>::arena(&ctx, "update", s.update_scratch_bytes.unwrap() as usize).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let before = ctx.traffic();
        builder
            .record_update_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
            .unwrap();
        let recorded = ctx.traffic() - before;
        assert_eq!(
            (
                recorded.upload_bytes,
                recorded.inline_bytes,
                recorded.device_allocations
            ),
            (0, 0, 0),
            "{kind:?}: the update uploads and allocates nothing"
        );
        rec.submit_and_wait().unwrap();
        let hits = trace(&ctx, kind, &g, &rays);
        let soup = TraceGeometry::from_triangles(&moved);
        for (r, h) in rays.iter().zip(&hits) {
            let b = cpu::brute_force(&soup, r, 0.0, &opt());
            assert!(common::same_answer(h, &b), "{kind:?}: {h:?} vs {b:?}");
        }
    }
    common::assert_silent(&ctx);
}

/// A byte copy of a built structure's placed range, recorded as built by copy
/// (`GpuGeometry::record_built_by_copy`: its own handle record, its source's build state),
/// traces as its source did once the source's memory is gone, and updates as the source
/// would have; a copy of a structure never built is refused.
#[test]
fn a_byte_copy_recorded_as_built_traces_and_updates_as_its_source() {
    let Some(ctx) = common::context() else { return };
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let moved: Vec<[Vec3; 3]> = tris
        .iter()
        .map(|t| t.map(|p| p * 0.8 + Vec3::new(-0.1, 0.2, 0.0)))
        .collect();
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        let mut caller = CallerBuffers::new();
        let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let sizes = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
        let n = sizes.structure_bytes as usize;
        let copy_mem = Buffer::<u8>::arena(&ctx, "caller.copy", n).unwrap();
        let mut copy = builder
            .create_in(&ctx, &geometries, &flags, unsafe { copy_mem.as_raw() })
            .unwrap();
        // A copy of a structure never built is refused.
        let unbuilt_mem = Buffer::<u8>::arena(&ctx, "caller.unbuilt", n).unwrap();
        let unbuilt = builder
            .create_in(&ctx, &geometries, &flags, unsafe { unbuilt_mem.as_raw() })
            .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let r = copy.record_built_by_copy(&mut rec, &unbuilt, unsafe { CopiedStructure::new() });
        assert!(
            matches!(r, Err(GpuError::NotBuilt { .. })),
            "{kind:?}: {r:?}"
        );
        drop(rec);

        // The source, referenceable (its build writes its handle record), and the copy.
        let source_mem = Buffer::<u8>::arena(&ctx, "caller.structure", n).unwrap();
        let scratch_mem =
            Buffer::<u8>::arena(&ctx, "caller.scratch", sizes.build_scratch_bytes as usize)
                .unwrap();
        let mut original = builder
            .create_in(&ctx, &geometries, &flags, unsafe { source_mem.as_raw() })
            .unwrap();
        original.enable_references();
        copy.enable_references();
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_build_from(&mut rec, &mut original, &geometries, unsafe {
                scratch_mem.as_raw()
            })
            .unwrap();
        rec.submit_and_wait().unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.copy(&source_mem, &copy_mem, n);
        copy.record_built_by_copy(&mut rec, &original, unsafe { CopiedStructure::new() })
            .unwrap();
        rec.transfer_to_indirect();
        rec.submit_and_wait().unwrap();
        // The copy's handle record (what a top level's instances reference) names its own
        // arrays, not the source's, which the byte copy brought.
        let words = |w: [u64; 7]| -> Vec<u8> { bytemuck::cast_slice(&w).to_vec() };
        let (own, source) = (
            words(copy.handle_words().unwrap()),
            words(original.handle_words().unwrap()),
        );
        let bytes = copy_mem.download().unwrap();
        let holds = |w: &[u8]| bytes.windows(w.len()).step_by(8).any(|b| b == w);
        assert!(holds(&own), "{kind:?}: the copy's own handle record");
        assert!(
            !holds(&source),
            "{kind:?}: the source's handle record in the copy"
        );
        // The source and its memory go: the copy stands on its own.
        drop(original);
        drop((source_mem, scratch_mem));
        let rays = rays_into(&tris, 300, 11);
        let soup = TraceGeometry::from_triangles(&tris);
        for (r, h) in rays.iter().zip(trace(&ctx, kind, &copy, &rays)) {
            let b = cpu::brute_force(&soup, r, 0.0, &opt());
            assert!(common::same_answer(&h, &b), "{kind:?} copy: {h:?} vs {b:?}");
        }
        // Updated as its source would have been.
        let flat: Vec<Vec3> = moved.iter().flatten().copied().collect();
        caller.bufs[0].upload(bytemuck::cast_slice(&flat)).unwrap();
        let scratch =
            Buffer::<u8>::arena(&ctx, "update", sizes.update_scratch_bytes.unwrap() as usize)
                .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_update_from(&mut rec, &mut copy, &geometries, unsafe {
                scratch.as_raw()
            })
            .unwrap();
        rec.submit_and_wait().unwrap();
        let rays = rays_into(&moved, 300, 12);
        let soup = TraceGeometry::from_triangles(&moved);
        for (r, h) in rays.iter().zip(trace(&ctx, kind, &copy, &rays)) {
            let b = cpu::brute_force(&soup, r, 0.0, &opt());
            assert!(
                common::same_answer(&h, &b),
                "{kind:?} updated copy: {h:?} vs {b:?}"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn misuse_is_an_error_not_a_panic() {
    let Some(ctx) = common::context() else { return };
    let tris = common::mesh_triangles(&vkrt::scene::gen::icosphere(1).unwrap());
    let mut caller = CallerBuffers::new();
    let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
    let vertices = match geometries[0] {
        Geometry::Triangles(Triangles {
            vertices: GeometryData::Buffer(v),
            ..
        }) => v,
        _ => unreachable!(),
    };
    let flags = BuildFlags::default();
    let lbvh = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    let is_usage = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::Usage { .. }) | Err(GpuError::Placement { .. }) => {}
        other => panic!("{what}: {other:?}"),
    };

    // Bad descriptions: stride, counts past the buffer, huge counts, misaligned indices,
    // non-opaque in a kd-tree (its walk may meet a primitive twice), a non-finite transform.
    let bad = |t: Triangles| {
        lbvh.sizes_for(&ctx, &[Geometry::Triangles(t)], &flags)
            .map(drop)
    };
    let n = tris.len() as u32 * 3;
    let ok = Triangles::soup(vertices, n);
    is_usage(bad(Triangles { stride: 10, ..ok }), "stride 10");
    is_usage(
        bad(Triangles {
            vertex_count: n + 1,
            ..ok
        }),
        "vertices past the buffer",
    );
    is_usage(
        bad(Triangles {
            triangle_count: u32::MAX / 2,
            ..ok
        }),
        "a huge count",
    );
    let non_opaque = [Geometry::Triangles(Triangles {
        opaque: false,
        ..ok
    })];
    is_usage(
        kd.sizes_for(&ctx, &non_opaque, &flags).map(drop),
        "non-opaque in a kd-tree",
    );
    assert!(bad(Triangles {
        opaque: false,
        ..ok
    })
    .is_ok());
    is_usage(
        bad(Triangles {
            transform: Some([[f32::NAN; 4]; 3].into()),
            ..ok
        }),
        "a NaN transform",
    );
    is_usage(
        bad(Triangles {
            // SAFETY: refused while recording, before anything could read it.
            transform: Some(Transform::at(unsafe { DeviceRange::new(0x1000, 48) })),
            ..ok
        }),
        "a transform at an address over vertices in a buffer",
    );
    is_usage(
        bad(Triangles {
            indices: Some(Indices {
                data: unsafe { RawBuffer::new(vertices.buffer(), 1, vertices.size()) }.into(),
                index_type: IndexType::U16,
            }),
            triangle_count: 1,
            ..ok
        }),
        "misaligned indices",
    );

    // Boxes: stride below a box, non-opaque in a kd-tree, more boxes than the range holds.
    let boxes = Aabbs {
        data: vertices.into(),
        stride: 24,
        count: (vertices.size() / 24) as u32,
        opaque: true,
    };
    let bad_boxes = |b: Aabbs| {
        lbvh.sizes_for(&ctx, &[Geometry::Aabbs(b)], &flags)
            .map(drop)
    };
    assert!(bad_boxes(boxes).is_ok());
    is_usage(
        bad_boxes(Aabbs {
            stride: 20,
            ..boxes
        }),
        "box stride 20",
    );
    is_usage(
        kd.sizes_for(
            &ctx,
            &[Geometry::Aabbs(Aabbs {
                opaque: false,
                ..boxes
            })],
            &flags,
        )
        .map(drop),
        "non-opaque boxes in a kd-tree",
    );
    is_usage(
        bad_boxes(Aabbs {
            count: boxes.count + 1,
            ..boxes
        }),
        "boxes past the range",
    );

    // The SAH BVH is a host builder.
    let sah = AccelBuilder::new(&ctx, AccelKind::SahBvh).unwrap();
    is_usage(
        sah.sizes_for(&ctx, &geometries, &flags).map(drop),
        "SAH BVH from device",
    );

    // Wrong kind, other geometry, unbuilt, refit of a kd-tree, update without allow_update.
    let (mut kd_g, _m1) = build_in_caller_memory(&ctx, &kd, &geometries, &flags);
    let scratch = Buffer::<u8>::arena(&ctx, "scratch", 1 << 20).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let into_kd = lbvh.record_build_from(&mut rec, &mut kd_g, &geometries, unsafe {
        scratch.as_raw()
    });
    assert!(
        matches!(&into_kd, Err(GpuError::KindMismatch { built, .. }) if built == "kdtree"),
        "an LBVH builder into a kd-tree: {into_kd:?}"
    );
    is_usage(
        kd.record_update_from(&mut rec, &mut kd_g, &geometries, unsafe {
            scratch.as_raw()
        }),
        "an update of a kd-tree",
    );
    let half = [soup_geometry(&ctx, &mut caller, &tris[..tris.len() / 2])];
    is_usage(
        kd.record_build_from(&mut rec, &mut kd_g, &half, unsafe { scratch.as_raw() }),
        "other geometry",
    );
    let s = lbvh.sizes_for(&ctx, &geometries, &flags).unwrap();
    let mem = Buffer::<u8>::arena(&ctx, "mem", s.structure_bytes as usize).unwrap();
    let mut unbuilt = lbvh
        .create_in(&ctx, &geometries, &flags, unsafe { mem.as_raw() })
        .unwrap();
    let r = lbvh.record_update_from(&mut rec, &mut unbuilt, &geometries, unsafe {
        scratch.as_raw()
    });
    assert!(
        matches!(r, Err(GpuError::NotBuilt { .. })),
        "an update of an unbuilt structure: {r:?}"
    );
    let tracer =
        Tracer::for_accel(&ctx, &opt(), AccelKind::Lbvh.walked(Default::default())).unwrap();
    let rays = Buffer::<Ray>::new(&ctx, "rays", 4).unwrap();
    let hits = Buffer::<Hit>::new(&ctx, "hits", 4).unwrap();
    let errors = Buffer::<u32>::new(&ctx, "errors", 1).unwrap();
    let r = tracer.record(&mut rec, &unbuilt, &rays, &hits, &errors, 4, 0.0);
    assert!(
        matches!(r, Err(GpuError::NotBuilt { .. })),
        "a trace of an unbuilt structure: {r:?}"
    );
    let (mut built, _m2) = build_in_caller_memory(&ctx, &lbvh, &geometries, &flags);
    is_usage(
        lbvh.record_update_from(&mut rec, &mut built, &geometries, unsafe {
            scratch.as_raw()
        }),
        "an update without allow_update",
    );
    // Ray counts past the buffers, and a tracer of another walk.
    is_usage(
        tracer.record(&mut rec, &built, &rays, &hits, &errors, 5, 0.0),
        "5 rays in buffers of 4",
    );
    let r = tracer.record(&mut rec, &kd_g, &rays, &hits, &errors, 4, 0.0);
    assert!(
        matches!(r, Err(GpuError::KindMismatch { .. })),
        "a BVH tracer on a kd-tree: {r:?}"
    );
    // Zero rays are nothing to do.
    tracer
        .record(&mut rec, &built, &rays, &hits, &errors, 0, 0.0)
        .unwrap();
    drop(rec);
    common::assert_silent(&ctx);
}

#[test]
fn a_kd_tree_that_runs_out_of_capacity_says_so_and_the_caller_grows_it() {
    let Some(ctx) = common::context() else { return };
    let tris = common::mesh_triangles(&vkrt::scene::gen::icosphere(1).unwrap());
    let rays = rays_into(&tris, 200, 9);
    let mut caller = CallerBuffers::new();
    let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
    let mut builder = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    // A budget far too small for the first build.
    builder = builder.with_kd_refs_per_level(Some(2));
    let mut flags = BuildFlags::default();
    let mut overflowed = 0;
    let (g, _mem) = loop {
        let (g, mem) = build_in_caller_memory(&ctx, &builder, &geometries, &flags);
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.compute_to_transfer();
        let status = g.record_read_status(&mut rec).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        let status = status.read().unwrap();
        assert_eq!(status.invalid_primitives, 0);
        if !status.kd_overflow {
            break (g, mem);
        }
        // An empty structure until then: every ray misses, never a truncated tree.
        assert!(trace(&ctx, AccelKind::KdTree, &g, &rays)
            .iter()
            .all(|h| !h.is_hit()));
        overflowed += 1;
        assert!(overflowed < 8, "still out of capacity");
        flags.kd_capacity_doublings += 1;
    };
    assert!(overflowed > 0, "the tiny budget never ran out");
    let soup = TraceGeometry::from_triangles(&tris);
    for (r, h) in rays.iter().zip(trace(&ctx, AccelKind::KdTree, &g, &rays)) {
        let b = cpu::brute_force(&soup, r, 0.0, &opt());
        assert!(common::same_answer(&h, &b), "{h:?} vs {b:?}");
    }
    common::assert_silent(&ctx);
}

#[test]
fn settings_are_frozen_into_the_structure_and_checked_at_every_record_call() {
    let Some(ctx) = common::context() else { return };
    let tris = common::mesh_triangles(&vkrt::scene::gen::icosphere(2).unwrap());
    let mut caller = CallerBuffers::new();
    let geometries = [soup_geometry(&ctx, &mut caller, &tris)];
    let rays = rays_into(&tris, 200, 9);
    // Wide nodes and updates, given at creation.
    let flags = BuildFlags {
        wide: true,
        allow_update: true,
        ..BuildFlags::default()
    };
    let lbvh = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let (mut g, mem) = build_in_caller_memory(&ctx, &lbvh, &geometries, &flags);
    assert!(g.structure().is_wide());
    assert_eq!(g.structure().flags(), flags);
    // A builder with other parameters (one primitive per leaf) cannot record into it: the
    // build, the update and the refit are each an error, and nothing is recorded.
    let other = AccelBuilder::new(&ctx, AccelKind::Lbvh)
        .unwrap()
        .with_bvh_params(vkrt::accel::bvh::BvhParams {
            max_leaf_prims: 1,
            ..Default::default()
        });
    let sizes = lbvh.sizes_for(&ctx, &geometries, &flags).unwrap();
    let scratch = Buffer::<u8>::arena(
        &ctx,
        "caller.scratch",
        sizes
            .build_scratch_bytes
            .max(sizes.update_scratch_bytes.unwrap()) as usize,
    )
    .unwrap();
    let is_frozen = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::FrozenSetting { frozen, given, .. }) => {
            assert!(
                frozen.contains("max_leaf_prims") && frozen != given,
                "{what}: {frozen}"
            )
        }
        other => panic!("{what}: {other:?}"),
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    is_frozen(
        other.record_build_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() }),
        "build",
    );
    is_frozen(
        other.record_update_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() }),
        "update",
    );
    let visits = other.update_scratch(&ctx, tris.len()).unwrap().unwrap();
    is_frozen(other.record_refit(&mut rec, &mut g, &visits), "refit");
    // The builder that made it rebuilds and updates it as created: still wide, walked wide
    // to brute force's hits (a builder's flags cannot change a structure's node format).
    lbvh.record_build_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
        .unwrap();
    lbvh.record_update_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
        .unwrap();
    rec.submit_and_wait().unwrap();
    assert!(g.structure().is_wide());
    let wide = Tracer::for_accel(&ctx, &opt(), AccelKind::Lbvh.walked(Traversal::Wide)).unwrap();
    let b = wide.trace(&ctx, &g, &rays, 0.0).unwrap();
    assert_eq!(b.exhausted, 0);
    let host = TraceGeometry::from_triangles(&tris);
    for (r, got) in rays.iter().zip(&b.hits) {
        let want = cpu::brute_force(&host, r, 0.0, &opt());
        assert!(common::same_answer(got, &want), "{got:?} against {want:?}");
    }
    // The host path freezes the builder's flags at `create` the same way.
    let wide_builder = AccelBuilder::new(&ctx, AccelKind::Ploc)
        .unwrap()
        .with_wide(true);
    let (s, _) = wide_builder.create(&ctx, tris.len(), 0).unwrap();
    assert!(s.is_wide() && s.flags().wide);
    drop((g, mem, scratch));
    common::assert_silent(&ctx);
}
