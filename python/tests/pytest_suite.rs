//! Runs the Python package's pytest suite as part of `cargo test --workspace`: a virtual
//! environment under the target folder (made once, with maturin, pytest, gymnasium, numpy
//! and the `bluesky` extra's bluesky and ophyd-async from PyPI), the module built into it
//! with `maturin develop`, then `pytest python/tests`. Skipped, loudly, only when there is no `python3` at all;
//! `OPTALIGN_PYTHON` names another interpreter.

use std::path::{Path, PathBuf};
use std::process::Command;

/// What the environment needs; a change here rebuilds it.
const REQUIREMENTS: &[&str] = &[
    "maturin>=1.9,<2",
    "pytest>=7",
    "gymnasium>=1.1,<2",
    "numpy>=1.22",
    // The `bluesky` extra, for the tests of optalign.bluesky under a real RunEngine.
    "bluesky>=1.14",
    "ophyd-async>=0.21,<0.22",
];

fn python() -> Option<String> {
    let name = std::env::var("OPTALIGN_PYTHON").unwrap_or_else(|_| "python3".into());
    let found = Command::new(&name)
        .arg("--version")
        .output()
        .is_ok_and(|out| out.status.success());
    found.then_some(name)
}

fn run(what: &str, command: &mut Command) {
    let status = command
        .status()
        .unwrap_or_else(|e| panic!("cannot start {what}: {e}"));
    assert!(status.success(), "{what} failed ({status})");
}

/// The cached virtual environment, (re)made when missing or its requirements changed.
fn environment(python: &str, venv: &Path) -> PathBuf {
    let bin = venv.join("bin");
    let marker = venv.join("optalign-requirements.txt");
    let wanted = REQUIREMENTS.join("\n");
    if std::fs::read_to_string(&marker).ok().as_deref() == Some(wanted.as_str()) {
        return bin;
    }
    let _ = std::fs::remove_dir_all(venv);
    run(
        "python3 -m venv (on Debian: apt-get install python3-venv)",
        Command::new(python).args(["-m", "venv"]).arg(venv),
    );
    run(
        "pip install of the test requirements",
        Command::new(bin.join("python"))
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .args(REQUIREMENTS),
    );
    std::fs::write(&marker, wanted).expect("cannot write the environment's marker");
    bin
}

#[test]
fn the_python_package_passes_its_pytest_suite() {
    let Some(python) = python() else {
        eprintln!(
            "\n*** SKIPPED: no python3 on this machine, so the Python package's pytest suite did not run ***\n"
        );
        return;
    };
    let package = Path::new(env!("CARGO_MANIFEST_DIR"));
    let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-venv");
    let bin = environment(&python, &venv);
    let path = std::env::join_paths(std::iter::once(bin.clone()).chain(std::env::split_paths(
        &std::env::var_os("PATH").unwrap_or_default(),
    )))
    .expect("PATH");
    run(
        "maturin develop (building the optalign module)",
        Command::new(bin.join("maturin"))
            .args(["develop", "--quiet", "--manifest-path"])
            .arg(package.join("Cargo.toml"))
            .env("VIRTUAL_ENV", &venv)
            .env("PATH", &path),
    );
    run(
        "pytest python/tests",
        Command::new(bin.join("python"))
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(package.join("tests"))
            .current_dir(package)
            .env("VIRTUAL_ENV", &venv)
            .env("PATH", &path),
    );
}
