//! What compaction saves: the Stanford bunny (`$VKRT_MESH`, else ../shared/scenes; without
//! it a generated icosphere) built over the renderer's buffers in memory of the sizes vkrt
//! reports, then
//!
//! - **kd-tree**: compacted (`GpuGeometry::record_compacted_size`, `create_compacted_in`,
//!   `record_compact_into`): compacted ÷ built bytes;
//! - **LBVH, PLOC** (not compacted: their buffers are sized for their primitives): the node
//!   slots the SAH leaf collapse freed, counted from the downloaded tree, and the bytes a
//!   copy without them would take (64-byte node and 4-byte parent link per slot) ÷ built.
//!
//! Sizes only, no timing. `cargo bench --bench compaction [-- --json]`

use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, IndexType, Triangles};
use vkrt::accel::host::HostStructure;
use vkrt::gpu::{Buffer, Context, ContextOptions, Recorder};

#[path = "common/args.rs"]
mod args;

#[derive(serde::Serialize)]
struct Row {
    kind: &'static str,
    triangles: usize,
    built_bytes: u64,
    /// The compacted structure's bytes (kd-tree), or those of the BVH without its freed
    /// node slots.
    compacted_bytes: u64,
    ratio: f64,
    /// LBVH, PLOC: node slots and the live nodes among them.
    node_slots: Option<usize>,
    live_nodes: Option<usize>,
}

fn main() {
    let args::BenchArgs { json, .. } = args::parse();
    let ctx = Context::new(&ContextOptions::default()).expect("a Vulkan device");
    let bunny = std::env::var_os("VKRT_MESH").map_or_else(
        || {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/scenes/stanford-bunny.obj")
        },
        std::path::PathBuf::from,
    );
    let mesh = if bunny.exists() {
        vkrt::scene::Scene::load(&bunny)
            .expect("the bunny")
            .scene
            .meshes[0]
            .clone()
    } else {
        eprintln!("{} not present: a generated icosphere", bunny.display());
        vkrt::scene::gen::icosphere(6).expect("an icosphere")
    };
    let vertices = Buffer::from_slice(&ctx, "renderer.vertices", &mesh.positions).unwrap();
    let flat: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
    let indices = Buffer::from_slice(&ctx, "renderer.indices", &flat).unwrap();
    let n = mesh.indices.len();
    let geometries = [Geometry::Triangles(Triangles::indexed(
        vertices.as_raw(),
        mesh.positions.len() as u32,
        indices.as_raw(),
        IndexType::U32,
        n as u32,
    ))];
    let flags = BuildFlags::default();
    let mut rows = Vec::new();
    for kind in [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc] {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let sizes = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
        let memory =
            Buffer::<u8>::arena(&ctx, "caller.structure", sizes.structure_bytes as usize).unwrap();
        let scratch =
            Buffer::<u8>::arena(&ctx, "caller.scratch", sizes.build_scratch_bytes as usize)
                .unwrap();
        let mut g = builder
            .create_in(&ctx, &geometries, &flags, memory.as_raw())
            .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_build_from(&mut rec, &mut g, &geometries, scratch.as_raw())
            .unwrap();
        rec.submit_and_wait().unwrap();
        let built = sizes.structure_bytes;
        let row = match kind {
            AccelKind::KdTree => {
                let mut rec = Recorder::new(&ctx).unwrap();
                rec.compute_to_transfer();
                let query = g.record_compacted_size(&mut rec).unwrap();
                rec.transfer_to_host();
                rec.submit_and_wait().unwrap();
                let size = query.read().unwrap();
                Row {
                    kind: kind.name(),
                    triangles: n,
                    built_bytes: built,
                    compacted_bytes: size.bytes,
                    ratio: size.bytes as f64 / built as f64,
                    node_slots: None,
                    live_nodes: None,
                }
            }
            _ => {
                let HostStructure::Bvh(tree) = g.structure().download().unwrap() else {
                    unreachable!("a BVH kind downloads a BVH")
                };
                let slots = n - 1;
                let live = tree.nodes.len();
                let without = built - (slots - live) as u64 * (64 + 4);
                Row {
                    kind: kind.name(),
                    triangles: n,
                    built_bytes: built,
                    compacted_bytes: without,
                    ratio: without as f64 / built as f64,
                    node_slots: Some(slots),
                    live_nodes: Some(live),
                }
            }
        };
        if !json {
            match (row.node_slots, row.live_nodes) {
                (Some(s), Some(l)) => println!(
                    "{:7} {} triangles: {} bytes built; {l} of {s} node slots live: {} bytes \
                     without the freed ones, ×{:.3} (not compacted)",
                    row.kind, row.triangles, row.built_bytes, row.compacted_bytes, row.ratio
                ),
                _ => println!(
                    "{:7} {} triangles: {} bytes built, {} compacted, ×{:.3}",
                    row.kind, row.triangles, row.built_bytes, row.compacted_bytes, row.ratio
                ),
            }
        }
        rows.push(row);
    }
    if json {
        println!("{}", serde_json::json!({ "compaction": rows }));
    }
}
