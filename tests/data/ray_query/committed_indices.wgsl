// The family `committed_indices` (tests/ray_query_families.rs) in WGSL, as wgpu's naga
// compiles it: every candidate decided, the committed indices written.
@group(0) @binding(0) var scene: acceleration_structure;
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> results: array<vec4<u32>>;
struct Count { ray_count: u32 }
var<push_constant> count: Count;

const SPHERES = array<vec4<f32>, 3>(vec4<f32>(0.0, 0.0, 3.0, 0.6), vec4<f32>(2.5, 2.5, 0.0, 0.8), vec4<f32>(-2.5, -2.0, 1.0, 0.5));

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= count.ray_count) { return; }
    let o = rays[2u * i];
    let d = rays[2u * i + 1u];
    var rq: ray_query;
    rayQueryInitialize(&rq, scene, RayDesc(0u, 0xffu, o.w, d.w, o.xyz, d.xyz));
    while (rayQueryProceed(&rq)) {
        let c = rayQueryGetCandidateIntersection(&rq);
        if (c.kind == RAY_QUERY_INTERSECTION_TRIANGLE) {
            rayQueryConfirmIntersection(&rq);
        } else {
            // The spheres' instance has the identity transform: object space is world space.
            let s = SPHERES[c.primitive_index];
            let oc = o.xyz - s.xyz;
            let a = dot(d.xyz, d.xyz);
            let b = dot(oc, d.xyz);
            let cc = dot(oc, oc) - s.w * s.w;
            let disc = b * b - a * cc;
            if (disc >= 0.0) {
                let t0 = (-b - sqrt(disc)) / a;
                let t1 = (-b + sqrt(disc)) / a;
                let t = select(t1, t0, t0 >= o.w);
                rayQueryGenerateIntersection(&rq, t);
            }
        }
    }
    let h = rayQueryGetCommittedIntersection(&rq);
    if (h.kind == RAY_QUERY_INTERSECTION_NONE) {
        results[i] = vec4<u32>(0xffffffffu);
        return;
    }
    let tri = h.kind == RAY_QUERY_INTERSECTION_TRIANGLE;
    let packed = h.kind | (select(0u, 1u, tri && h.front_face) << 2u) | (h.instance_index << 3u) | (h.geometry_index << 9u);
    results[i] = vec4<u32>(h.primitive_index, h.instance_custom_data, h.sbt_record_offset, packed);
}
