//! See the module docs of `crate::accuracy`.
