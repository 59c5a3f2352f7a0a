//! Commands of the `vkrt` binary that have grown past a few lines (the others live in
//! `main.rs`).

pub mod animate;
pub mod verify;
