//! What the `vkrt` command line measures, shared by its commands and its benches
//! (`cargo bench --bench NAME`): the copy baselines and the primitive and kd-tree benches
//! ([`bench`](mod@bench)), ray throughput of every structure ([`trace_bench`]), Sochora's build-time
//! tables ([`bvh_bench`]), what each render effect costs ([`render_bench`]), the accuracy
//! report with its plots ([`accuracy`]), the animation's per-frame plot ([`animate_plot`])
//! and the long runs ([`soak`]). The library, `vkrt`, holds nothing of these.

#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod accuracy;
pub mod animate_plot;
pub mod bench;
pub mod bvh_bench;
pub mod render_bench;
pub mod soak;
pub mod trace_bench;
