//! The command line of the benches that print a table (`cargo bench --bench NAME -- ...`):
//! one parser for all of them, so each takes the same flags and refuses a misspelt one.

/// What a bench's caller asked for; a bench reads the flags it has.
#[derive(clap::Parser)]
#[command(about = "A vkrt benchmark: prints its table, or JSON with --json")]
#[allow(dead_code, reason = "not every bench reads every flag")]
pub struct BenchArgs {
    /// Print one JSON document instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Smaller scenes and fewer repetitions.
    #[arg(long)]
    pub quick: bool,
    /// Camera image width in pixels, one primary ray per pixel (the trace bench).
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Passed by `cargo bench` itself.
    #[arg(long, hide = true)]
    bench: bool,
}

/// The process's arguments, parsed (help and errors printed by clap, which then exits).
pub fn parse() -> BenchArgs {
    clap::Parser::parse()
}
