//! The commands of the `vkrt` binary, one file each (`bench` one per subcommand): each
//! holds its clap arguments (`*Args`) and a `run`; `main.rs` only parses and dispatches.
//! What several commands share (the device context, logging, scene loading, the `*Arg`
//! value enums) is in `common`.

pub mod animate;
pub mod bench;
pub mod build;
pub mod common;
pub mod info;
pub mod lower;
pub mod render;
pub mod scene;
pub mod shader_check;
pub mod trace;
pub mod verify;
