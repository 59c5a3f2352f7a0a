//! The guides that ship with the crate: the pages of `docs/` a user of the library reads,
//! included here so that they are read where the API is.

#[doc = include_str!("../docs/embedding.md")]
pub mod embedding {}

#[doc = include_str!("../docs/versioning.md")]
pub mod versioning {}

#[doc = include_str!("../docs/ray-queries.md")]
pub mod ray_queries {}
