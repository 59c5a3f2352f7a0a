//! The SPIR-V pass (`vkrt::spirv::lower_ray_queries`): never panics; a module it lowers
//! declares no ray-query capability; an error names what it refuses. Input: SPIR-V bytes
//! (seed with modules that use ray queries: `fuzz/README.md`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use vkrt::spirv::{has_ray_queries, lower_ray_queries, LowerOptions};

fuzz_target!(|data: &[u8]| {
    let words: Vec<u32> = data
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    match lower_ray_queries(&words, &LowerOptions::default()) {
        Ok(lowered) if lowered.changed => assert!(!has_ray_queries(&lowered.words)),
        Ok(lowered) => assert_eq!(lowered.words, words),
        Err(e) => assert!(!e.to_string().is_empty()),
    }
});
