//! The `optalign` command.
fn main() {}
