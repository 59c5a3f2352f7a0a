//! `vkrt lower`: the SPIR-V pass (`vkrt::spirv`) as a command: a shader's ray queries
//! rewritten into calls of vkrt's walk, for a device without `VK_KHR_ray_query`.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use super::common::CliResult;

#[derive(Args)]
pub struct LowerArgs {
    /// The SPIR-V module (from glslang, DXC, Slang, naga, ...).
    input: PathBuf,
    /// Where to write the lowered module (atomically; nothing is written on an error).
    #[arg(short, long)]
    output: PathBuf,
    /// The specialization constant id of the walk's step cap in the lowered module.
    #[arg(long, default_value_t = vkrt::accel::shader_library::STEPS_CONSTANT_ID)]
    steps_constant_id: u32,
    /// Link the walk for a device with a loop budget (Mesa 22.3's lavapipe; `vkrt info`
    /// says whether the device has one): it spends about a quarter of the budget.
    #[arg(long)]
    loop_budget: bool,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &LowerArgs) -> CliResult<()> {
    let bytes = std::fs::read(&args.input)
        .map_err(|e| format!("{}: cannot read: {e}", args.input.display()))?;
    if bytes.len() % 4 != 0 {
        return Err(format!(
            "{}: {} bytes: SPIR-V is a whole number of 32-bit words",
            args.input.display(),
            bytes.len()
        )
        .into());
    }
    let words: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
    let options = vkrt::spirv::LowerOptions {
        steps_constant_id: args.steps_constant_id,
        loop_budget: args.loop_budget,
    };
    let start = Instant::now();
    let lowered = vkrt::spirv::lower_ray_queries(&words, &options)
        .map_err(|e| format!("{}: {e}", args.input.display()))?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    vkrt::gpu::write_atomically(&args.output, bytemuck::cast_slice(&lowered.words))?;
    if args.json {
        let v = serde_json::json!({
            "changed": lowered.changed,
            "ray_query_instructions": lowered.instructions,
            "query_states": lowered.query_states,
            "structures": lowered.structures,
            "functions_linked": lowered.functions_linked,
            "words_in": words.len(),
            "words_out": lowered.words.len(),
            "ms": ms,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if lowered.changed {
        println!(
            "{}: {} ray-query instructions, {} query states per invocation, {} structure \
             bindings; {} library functions linked; {} words in, {} out; {ms:.2} ms; wrote {}",
            args.input.display(),
            lowered.instructions,
            lowered.query_states,
            lowered.structures,
            lowered.functions_linked,
            words.len(),
            lowered.words.len(),
            args.output.display()
        );
    } else {
        println!(
            "{}: no ray query: written unchanged to {}",
            args.input.display(),
            args.output.display()
        );
    }
    Ok(())
}
