//! The `dc_loc` binary: a ROS 2 node by default (`dc_loc --ros-args ...`), or one of the offline
//! subcommands (`dc_loc sim | run | eval | demo | revisits | params`, see `dc_loc help`).
#![forbid(unsafe_code)]

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let code = match args.get(1).map(String::as_str) {
        Some(
            "sim" | "run" | "eval" | "demo" | "revisits" | "params" | "help" | "--help" | "-h"
            | "--version" | "-V",
        ) => dc_loc::cli::main(&args),
        _ => dc_loc::cli::node_main(&args),
    };
    std::process::exit(code);
}
