//! Diagnostic logging to stderr through `tracing`, filtered by `-v` or `RUST_LOG`;
//! coloured only on a terminal and never with `NO_COLOR` set.

use tracing_subscriber::EnvFilter;

/// Installs the subscriber: warnings by default, more with each `-v`; `RUST_LOG` wins.
pub fn init(verbosity: u8) {
    let default = match verbosity {
        0 => "warn",
        1 => "info,optalign=info",
        2 => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(crate::console::colours_on_stderr())
        .with_target(false)
        .try_init();
}
