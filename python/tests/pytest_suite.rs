//! Runs the Python package's pytest suite as part of `cargo test --workspace`: a virtual
//! environment under the target folder (made once, with pytest, gymnasium, numpy and the
//! `bluesky` extra's bluesky and ophyd-async from PyPI), the package staged beside it (its
//! Python sources and the extension module that this very `cargo test` built, so the module
//! is not compiled a second time by maturin with other features), then `pytest python/tests`. Skipped, loudly, only when there is no
//! `python3` at all; `OPTALIGN_PYTHON` names another interpreter.

use std::path::{Path, PathBuf};
use std::process::Command;

/// What the environment needs; a change here rebuilds it.
const REQUIREMENTS: &[&str] = &[
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

/// The extension module cargo built for this test run (`python/Cargo.toml` makes the
/// library a `cdylib` too, and `.cargo/config.toml` builds PyO3 as an extension module, as
/// maturin would): beside the test binary in the target's `deps` folder.
fn extension_module() -> PathBuf {
    let test_binary = std::env::current_exe().expect("the test binary's path");
    let module = test_binary
        .parent()
        .expect("the target's deps folder")
        .join(format!(
            "{}_native{}",
            std::env::consts::DLL_PREFIX,
            std::env::consts::DLL_SUFFIX
        ));
    assert!(
        module.is_file(),
        "the extension module {} was not built",
        module.display()
    );
    module
}

/// Copies the `optalign` package's Python sources and the extension module into `stage`
/// (emptied first) and returns it, ready for `PYTHONPATH`.
fn stage_package(package: &Path, stage: &Path) -> PathBuf {
    let _ = std::fs::remove_dir_all(stage);
    copy_sources(&package.join("optalign"), &stage.join("optalign"));
    std::fs::copy(
        extension_module(),
        stage.join("optalign").join("_native.abi3.so"),
    )
    .expect("cannot stage the extension module");
    stage.to_path_buf()
}

/// Copies the `.py` files of `from` and its subpackages into `to`.
fn copy_sources(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("cannot make the staging folder");
    for entry in std::fs::read_dir(from).expect("the package's sources") {
        let path = entry.expect("a package entry").path();
        if path.is_dir() && path.file_name().is_some_and(|name| name != "__pycache__") {
            copy_sources(&path, &to.join(path.file_name().unwrap()));
        } else if path.extension().is_some_and(|ext| ext == "py") {
            std::fs::copy(&path, to.join(path.file_name().unwrap()))
                .expect("cannot stage a Python source");
        }
    }
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
    let staged = stage_package(
        package,
        &Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-package"),
    );
    run(
        "pytest python/tests",
        Command::new(bin.join("python"))
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(package.join("tests"))
            .current_dir(&staged)
            .env("PYTHONPATH", &staged),
    );
}
