//! `vkrt info`: the Vulkan device vkrt uses and what it can do, as text or JSON.

use clap::Args;

use super::common::{context, CliResult};

#[derive(Args)]
pub struct InfoArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &InfoArgs, validate: bool) -> CliResult<()> {
    let ctx = context(validate)?;
    let info = ctx.info();
    let walk = vkrt::accel::walk::Traversal::for_device(&ctx);
    if args.json {
        // The device's facts, and the walk and nodes vkrt's kernels take from them.
        let mut v = serde_json::to_value(info)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("bvh_walk".into(), walk.name().into());
            o.insert("bvh_nodes".into(), walk.node_layout().into());
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("device              {} ({})", info.device, info.device_type);
    println!("driver              {}", info.driver);
    println!("vulkan              {}", info.api_version);
    println!(
        "subgroup size       {} (min {}, max {})",
        info.subgroup_size, info.min_subgroup_size, info.max_subgroup_size
    );
    println!("subgroup ops        {}", info.subgroup_ops.join(" "));
    println!(
        "max storage buffer  {} bytes",
        info.max_storage_buffer_range
    );
    println!("max shared memory   {} bytes", info.max_shared_memory);
    println!(
        "workgroups          {} invocations, size {:?}, count {:?}",
        info.max_workgroup_invocations, info.max_workgroup_size, info.max_workgroup_count
    );
    println!(
        "timestamps          {} (period {} ns)",
        if info.timestamps { "yes" } else { "no" },
        info.timestamp_period_ns
    );
    println!(
        "f32 division        {}",
        if info.ieee_division {
            "correctly rounded"
        } else {
            "within Vulkan's 2.5 ulp: the exact walks round it correctly"
        }
    );
    match info.loop_budget {
        Some(b) => println!("loop budget         {b} iterations per invocation"),
        None => println!("loop budget         none (loops run to their end)"),
    }
    println!(
        "walk step cap       {} node visits + primitive tests per ray",
        info.max_traversal_steps
    );
    println!(
        "walks read          {} buffers (texel views up to {} texels)",
        vkrt::accel::walk::NodeAccess::for_device(&ctx).name(),
        info.max_texel_buffer_elements
    );
    println!(
        "kernel bindings     {}",
        match info.features.push_descriptor {
            true => "pushed (VK_KHR_push_descriptor): recording creates no descriptor set",
            false =>
                "descriptor sets (pushed where a context enables VK_KHR_push_descriptor, \
                      as the layer does)",
        }
    );
    let why = match (std::env::var("VKRT_TRAVERSAL").is_ok(), info.wide_walks) {
        (true, _) => "as VKRT_TRAVERSAL says",
        (false, true) => "lavapipe from Mesa 25.1: the 4-wide walk measured fastest there",
        (false, false) => "the 4-wide walk is not faster in every measured case here",
    };
    println!(
        "BVH walk            {} ({why}; --traversal auto)",
        walk.name()
    );
    println!(
        "BVH nodes           {} (the walk's; measured against the driver's shape, one \
         triangle per leaf: cargo bench --bench leaf_layout)",
        walk.node_layout()
    );
    Ok(())
}
