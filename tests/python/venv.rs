//! The Python venv of the ROS 2 tests, for Rust integration tests.
//!
//! Include it from a test file in `tests/` with
//! `#[path = "python/venv.rs"] mod venv;`, then run a script of `tests/python/` with
//! [`python_script`]`("test_x.py").output()`.
//!
//! Entry points: [`venv_python`] (runs `tests/python/setup_venv.sh` once per test binary and returns the
//! venv's interpreter, `<repo>/.venv/bin/python` or `$DCLOC_VENV/bin/python`), [`python_script`],
//! [`repo_root`]. The setup script is idempotent and takes a lock, so test binaries and tests running at
//! the same time share one build; a current venv costs well under a second.
//!
//! DDS stays on loopback: the scripts take their domain id and loopback settings from
//! `tests/python/dcloc_testlib.py`; [`python_script`] also sets `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`
//! and drops variables that would widen discovery, for anything the script starts before that.
#![allow(dead_code)] // each test binary uses its own subset

use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;

/// The repository root (the crate's manifest directory).
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The venv directory: `$DCLOC_VENV` if set (as `setup_venv.sh` reads it), else `<repo>/.venv`.
pub fn venv_dir() -> PathBuf {
    std::env::var_os("DCLOC_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".venv"))
}

/// The venv's Python interpreter, after making sure the venv is complete and current.
///
/// Runs `tests/python/setup_venv.sh` on the first call in this process (a no-op when nothing changed;
/// from scratch about 1.5 to 2 min: pip wheels, then cmake builds `msg/`). Panics with the script's
/// output if it fails.
pub fn venv_python() -> PathBuf {
    static PYTHON: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    let result = PYTHON.get_or_init(|| {
        let script = repo_root().join("tests/python/setup_venv.sh");
        let output = Command::new("bash")
            .arg(&script)
            .current_dir(repo_root())
            .output()
            .map_err(|e| format!("cannot run {}: {e}", script.display()))?;
        let log = format!(
            "{}{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        if !output.status.success() {
            return Err(format!(
                "{} failed ({}):\n{log}",
                script.display(),
                output.status
            ));
        }
        eprint!("{log}");
        let python = venv_dir().join("bin/python");
        if python.is_file() {
            Ok(python)
        } else {
            Err(format!(
                "{} succeeded but {} is missing",
                script.display(),
                python.display()
            ))
        }
    });
    match result {
        Ok(python) => python.clone(),
        Err(e) => panic!("{e}"),
    }
}

/// A command running `tests/python/<script>` with the venv's interpreter, from the repository root.
pub fn python_script(script: &str) -> Command {
    let mut command = Command::new(venv_python());
    command
        .arg(repo_root().join("tests/python").join(script))
        .current_dir(repo_root())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env_remove("PYTHONPATH")
        .env_remove("ROS_LOCALHOST_ONLY")
        .env_remove("ROS_STATIC_PEERS")
        .env_remove("ROS_DISCOVERY_SERVER");
    command
}
