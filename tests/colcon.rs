//! The ament package as a ROS 2 user builds it: `colcon build` of msg/ (colcon from PyPI, the Jazzy
//! ament and rosidl wheels of the test venv as the underlay) installs the interfaces, the node where
//! `ros2 run dc_loc dc_loc` finds it (lib/dc_loc/dc_loc), the launch file and the parameter files. The
//! node installed is this test's binary (`-DDC_LOC_NODE_BINARY`): the package's own `cargo build` step
//! is the same command as README.md's build and is not repeated here.

#[path = "python/venv.rs"]
mod venv;

mod common;
use common::text;
use std::process::Command;

#[test]
fn colcon_build_installs_interfaces_node_launch_file_and_parameters() {
    let python = venv::venv_python();
    let venv_dir = venv::venv_dir();
    let bin = venv_dir.join("bin");
    let ws = common::scratch("colcon_tests", "ws");
    let repo = venv::repo_root();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out = Command::new(bin.join("colcon"))
        .current_dir(&ws)
        .env("AMENT_PREFIX_PATH", &venv_dir)
        .env("CMAKE_PREFIX_PATH", &venv_dir)
        .env("PATH", &path)
        .env_remove("PYTHONPATH")
        .args(["build", "--base-paths"])
        .arg(repo.join("msg"))
        .arg("--cmake-args")
        .arg(format!("-DPython3_EXECUTABLE={}", python.display()))
        .arg("-DBUILD_TESTING=OFF")
        .arg(format!(
            "-DDC_LOC_NODE_BINARY={}",
            env!("CARGO_BIN_EXE_dc_loc")
        ))
        .output()
        .expect("cannot start colcon (tests/python/setup_venv.sh installs it)");
    print!("{}", text(&out.stdout));
    assert!(
        out.status.success(),
        "colcon build failed:\n{}\n{}",
        text(&out.stdout),
        text(&out.stderr)
    );

    let prefix = ws.join("install/dc_loc");
    for file in [
        "lib/dc_loc/dc_loc",
        "share/dc_loc/package.xml",
        "share/dc_loc/msg/LoopClosure.msg",
        "share/dc_loc/launch/dc_loc.launch.py",
        "share/dc_loc/params/dc_loc.yaml",
        "share/ament_index/resource_index/packages/dc_loc",
    ] {
        assert!(prefix.join(file).is_file(), "{file} not installed");
    }
    // The installed node runs; the installed Python interfaces import and serialize.
    let out = Command::new(prefix.join("lib/dc_loc/dc_loc"))
        .arg("--version")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let site = std::fs::read_dir(prefix.join("lib"))
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path().join("site-packages"))
        .find(|p| p.is_dir())
        .expect("no site-packages under install/dc_loc/lib");
    let out = Command::new(&python)
        .env("PYTHONPATH", &site)
        .args([
            "-c",
            "import dc_loc.msg as m, rclpy.serialization as s\n\
             assert m.__file__.startswith(__import__('sys').argv[1]), m.__file__\n\
             c = m.LoopClosure(query_id=3)\n\
             assert s.deserialize_message(s.serialize_message(c), m.LoopClosure).query_id == 3",
        ])
        .arg(&site)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the installed interfaces: {}",
        text(&out.stderr)
    );
}
