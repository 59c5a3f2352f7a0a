//! What compaction saves: the Stanford bunny (`$VKRT_MESH`, else ../shared/scenes; without
//! it a generated icosphere) built over the renderer's buffers in memory of the sizes vkrt
//! reports, then compacted (`GpuGeometry::record_compacted_size`, `create_compacted_in`,
//! `record_compact_into`) into memory of the size the query reports: compacted ÷ built
//! bytes for the kd-tree (its capacity's unused part), the LBVH and PLOC (the node slots
//! their SAH leaf collapse freed: the live nodes of all the slots, and the scratch their
//! renumbering takes).
//!
//! Sizes only, no timing. `cargo bench --bench compaction [-- --json]`

use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, IndexType, Triangles};
use vkrt::gpu::{Buffer, Context, ContextOptions, RawBuffer, Recorder};

#[path = "common/args.rs"]
mod args;

#[derive(serde::Serialize)]
struct Row {
    kind: &'static str,
    triangles: usize,
    built_bytes: u64,
    /// The compacted structure's bytes.
    compacted_bytes: u64,
    ratio: f64,
    /// The scratch of the compaction (0 for the kd-tree's copies).
    scratch_bytes: u64,
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
        unsafe { vertices.as_raw() },
        mesh.positions.len() as u32,
        unsafe { indices.as_raw() },
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
            .create_in(&ctx, &geometries, &flags, unsafe { memory.as_raw() })
            .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_build_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
            .unwrap();
        rec.submit_and_wait().unwrap();
        let built = sizes.structure_bytes;
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.compute_to_transfer();
        let query = g.record_compacted_size(&mut rec).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        let size = query.read().unwrap();
        let compacted_memory =
            Buffer::<u8>::arena(&ctx, "caller.compacted", size.bytes as usize).unwrap();
        let compact_scratch = Buffer::<u8>::arena(
            &ctx,
            "caller.compact_scratch",
            size.scratch_bytes.max(4) as usize,
        )
        .unwrap();
        let mut compacted = g
            .create_compacted_in(&ctx, &size, unsafe { compacted_memory.as_raw() })
            .unwrap();
        let scratch_range = (size.scratch_bytes > 0).then(|| unsafe {
            RawBuffer::new(
                compact_scratch.as_raw().buffer(),
                compact_scratch.as_raw().offset(),
                size.scratch_bytes,
            )
        });
        let mut rec = Recorder::new(&ctx).unwrap();
        g.record_compact_into(&mut rec, &mut compacted, scratch_range)
            .unwrap();
        rec.submit_and_wait().unwrap();
        let bvh = kind != AccelKind::KdTree;
        let row = Row {
            kind: kind.name(),
            triangles: n,
            built_bytes: built,
            compacted_bytes: size.bytes,
            ratio: size.bytes as f64 / built as f64,
            scratch_bytes: size.scratch_bytes,
            node_slots: bvh.then(|| n.saturating_sub(1).max(1)),
            live_nodes: bvh.then_some(size.nodes as usize),
        };
        if !json {
            let live = match (row.node_slots, row.live_nodes) {
                (Some(s), Some(l)) => format!(" ({l} of {s} node slots live)"),
                _ => String::new(),
            };
            println!(
                "{:7} {} triangles: {} bytes built, {} compacted{live}, ×{:.3}; {} bytes of \
                 scratch",
                row.kind,
                row.triangles,
                row.built_bytes,
                row.compacted_bytes,
                row.ratio,
                row.scratch_bytes
            );
        }
        rows.push(row);
    }
    if json {
        println!("{}", serde_json::json!({ "compaction": rows }));
    }
}
