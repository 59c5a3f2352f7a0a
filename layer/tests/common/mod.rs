#[allow(dead_code)] // the bench uses what the tests do not
pub mod app;
