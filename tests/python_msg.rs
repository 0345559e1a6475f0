//! The `dc_loc` interface package (`msg/`) as real ROS 2 users see it.
//!
//! Builds the Python venv if needed (`tests/python/setup_venv.sh`: Jazzy rclpy from PyPI, cyclonedds,
//! and `msg/` built with cmake into the venv), then runs `tests/python/test_loop_closure_msg.py`: an rclpy
//! publisher (reliable, transient-local, depth 100) sends `dc_loc/msg/LoopClosure` messages with every
//! field set to distinctive values; rclpy and Cyclone DDS subscribers, started before and after the
//! publishing (transient-local history), must receive each field exactly, and see the DDS type name
//! `dc_loc::msg::dds_::LoopClosure_` on topic `rt/<topic>`. All DDS traffic stays on loopback, in a
//! domain id the script reserves for itself.

#[path = "python/venv.rs"]
mod venv;

#[test]
fn loop_closure_reaches_rclpy_and_cyclonedds_subscribers_intact() {
    let output = venv::python_script("test_loop_closure_msg.py")
        .output()
        .expect("cannot start the venv's python");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    print!("{stdout}");
    eprint!("{stderr}");
    assert!(
        output.status.success(),
        "test_loop_closure_msg.py failed ({}); its output is above",
        output.status
    );
    // The script's own summary guards against one that exits 0 without checking everything: it runs 43
    // checks (8 messages: 24 without DDS, 14 at the four subscribers, 5 clean exits).
    let summary = stdout
        .lines()
        .rev()
        .find(|line| line.ends_with(" failed"))
        .expect("no summary line from test_loop_closure_msg.py");
    let passed: usize = summary
        .split(' ')
        .next()
        .and_then(|n| n.parse().ok())
        .expect("malformed summary line");
    assert!(
        summary.ends_with(" 0 failed") && passed >= 43,
        "unexpected summary: {summary}"
    );
}
