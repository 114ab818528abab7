//! The host's end-to-end tests, in one binary so that the workspace links one large test
//! executable instead of one per file: each module is one family of checks (run one with
//! `cargo test -p optalign --test integration <module>::`).
//!
//! Two stay binaries of their own: `lab_rig` puts the lab key in the process environment,
//! and `soak` watches the resident memory of its process, which no other test may share.

mod baselines_runs;
mod beams_cli;
mod bench_outputs;
mod cameras_cli;
mod demo_cli;
mod devtools;
mod fault_proxy;
mod faulty_link;
mod fuzz_inputs;
mod hijack;
mod hostile_clients;
mod input_bounds;
mod jog_cli;
mod kill_campaign;
mod monitor;
mod operator_stop;
mod peer_limits;
mod power_cut;
mod rehearsal;
mod rezero_cli;
mod sim_rig;
mod stalled_peer;
mod trust;
mod vision_agent;
mod vlm_cli;
mod vlm_http;

/// The `optalign` binary that the command-line tests run.
const BIN: &str = env!("CARGO_BIN_EXE_optalign");
