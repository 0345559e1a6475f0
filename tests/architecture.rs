//! The workspace's crates depend on each other one way, and each leaves out what its job does not need
//! (docs/architecture.md): the compiler keeps modules of one crate from reaching into a crate above it,
//! and this test keeps each crate's dependency tree free of the crates named below.

use std::process::Command;

/// What each crate must not have anywhere in its normal dependency tree.
const FORBIDDEN: [(&str, &[&str]); 4] = [
    (
        "dc_loc_core",
        &[
            "dc_loc_io",
            "dc_loc_node",
            "dc_loc_lab",
            "rustdds",
            "ros2-client",
            "tokio",
            "clap",
            "plotters",
            "indicatif",
            "env_logger",
            "prost",
            "mcap",
        ],
    ),
    (
        "dc_loc_io",
        &[
            "dc_loc_node",
            "dc_loc_lab",
            "rustdds",
            "ros2-client",
            "tokio",
            "clap",
            "plotters",
            "indicatif",
        ],
    ),
    (
        "dc_loc_lab",
        &[
            "dc_loc_node",
            "rustdds",
            "ros2-client",
            "tokio",
            "clap",
            "indicatif",
        ],
    ),
    // (ros2-client itself brings clap.)
    ("dc_loc_node", &["dc_loc_lab", "plotters", "indicatif"]),
];

/// The names of the packages in `krate`'s normal dependency tree (itself included).
fn dependency_tree(krate: &str) -> Vec<String> {
    let out = Command::new(env!("CARGO"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "tree",
            "--offline",
            "--locked",
            "-e",
            "normal",
            "--prefix",
            "none",
            "-p",
            krate,
        ])
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree -p {krate}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .expect("cargo tree prints UTF-8")
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect()
}

#[test]
fn each_crate_leaves_out_what_its_job_does_not_need() {
    for (krate, forbidden) in FORBIDDEN {
        let tree = dependency_tree(krate);
        assert!(
            tree.iter().any(|p| p == krate),
            "{krate} is not in its own tree: {tree:?}"
        );
        let found: Vec<_> = forbidden
            .iter()
            .filter(|f| tree.iter().any(|p| p == *f))
            .collect();
        assert!(found.is_empty(), "{krate} depends on {found:?}");
    }
}

#[test]
fn the_core_needs_only_the_numerics_and_serde() {
    let tree = dependency_tree("dc_loc_core");
    for needed in ["nalgebra", "kiddo", "rayon", "serde"] {
        assert!(
            tree.iter().any(|p| p == needed),
            "dc_loc_core without {needed}: {tree:?}"
        );
    }
}
