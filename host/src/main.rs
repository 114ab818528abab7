//! The `optalign` command: parses the command line, runs one subcommand, and reports any
//! failure as a single line on stderr with a non-zero exit status.

use std::process::ExitCode;

use clap::Parser;
use optalign::cli::Cli;

fn main() -> ExitCode {
    let cli = Cli::parse();
    optalign::logging::init(cli.verbose);
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(runtime) => runtime,
        Err(error) => {
            eprintln!("error: cannot start the async runtime: {error}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(cli.run()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", optalign::console::one_line(&error));
            ExitCode::FAILURE
        }
    }
}
