//! Who a parameter is for: the sensor setup a user must describe, the tuning knobs a user may turn
//! (each with guidance), and the internal constants and operational limits whose defaults serve every
//! robot tested. The node and `dc_loc run` accept all three alike; the split decides what README_NODE.md
//! shows (setup and tuning) and what docs/parameters.md keeps (the rest).

/// A parameter's audience.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Tier {
    /// What the robot is: its frames, topics, radars and their noise. Must be set.
    Setup,
    /// What a user may tune, with guidance on when and which way.
    Tuning,
    /// Method constants and operational limits: change them only to experiment.
    Internal,
}

/// The sensor setup (per-radar parameters as `radars.<name>.field`).
pub const SETUP: &[&str] = &[
    "radar_names",
    "body_frame",
    "odometry.topic",
    "radars.<name>.topic",
    "radars.<name>.message",
    "radars.<name>.frame_id",
    "radars.<name>.extrinsic",
    "radars.<name>.beta",
    "radars.<name>.sigma_range",
    "radars.<name>.sigma_azimuth",
    "radars.<name>.sigma_velocity",
    "radars.<name>.fields.x",
    "radars.<name>.fields.y",
    "radars.<name>.fields.z",
    "radars.<name>.fields.velocity",
    "radars.<name>.fields.velocity_x",
    "radars.<name>.fields.velocity_y",
    "radars.<name>.fields.rcs",
    "node.extrinsics_from_tf",
    "loop.extrinsic_std",
    "loop.clock_std",
    "submap.height_band",
    "map.file",
];

/// The tuning knobs and when to turn them.
pub const TUNING: &[(&str, &str)] = &[
    (
        "use_sim_time",
        "On when replaying a bag that publishes `/clock`.",
    ),
    (
        "keyframe.distance",
        "Lower (2-3 m) for slow robots and short revisits; higher saves CPU and map memory on fast \
         vehicles.",
    ),
    (
        "ego_motion.inlier_threshold",
        "About 3 times `sigma_velocity` of your radars; raise it if `/diagnostics` reports many Doppler \
         fit failures on a static scene.",
    ),
    (
        "loop.enabled",
        "Off to build the map only (no revisit search, no registration cost).",
    ),
    (
        "loop.drift_rate",
        "Your odometry's worst translation drift per metre driven. Too low holds a session's first \
         closures for four confirmations and refuses true closures after long gaps as `inconsistent`; \
         too high searches wider, registers more candidates and lets an accepted alignment vouch for a \
         street slid by a car length, which a short-range radar cannot tell apart (docs/experiments.md, \
         TI-class radar).",
    ),
    (
        "loop.drift_yaw_rate",
        "Your odometry's worst heading drift per metre: the gyro bias over the typical speed (0.3 deg/s \
         at 10 m/s is 5e-4 rad/m). Too low refuses true closures after long loops.",
    ),
    (
        "loop.minimum_path_gap",
        "Path driven before the robot may close onto its own trail; raise it above the longest \
         back-and-forth your robot drives.",
    ),
    (
        "loop.minimum_inliers",
        "Raise (20-30) where places repeat (car parks, arcades) and precision matters most; lower (10) \
         for one sparse radar.",
    ),
    (
        "loop.minimum_overlap",
        "Raise for precision on repetitive streets; lower for sparse radars whose submaps share little.",
    ),
    (
        "loop.maximum_translation_std",
        "Closures less certain than this are refused; a back end with a robust kernel can take more \
         (1 m).",
    ),
    (
        "loop.consistency_chi2",
        "The gate against odometry: lower is stricter. 0 disables it; keep it unless the odometry is \
         unreliable and the back end robust.",
    ),
    (
        "loop.confirmations",
        "1 publishes the first closure onto the robot's own trail at once (at the risk of one aliased \
         match); 3 for worlds that repeat.",
    ),
    (
        "map.max_keyframes",
        "The map's memory bound: set it from your RAM budget (tens of KB a keyframe for automotive \
         radars; `/diagnostics` reports the map's size).",
    ),
    (
        "node.robot_id",
        "A distinct id per robot when a multi-robot back end reads the PoseGraph output.",
    ),
    (
        "node.pose_graph_output",
        "On for back ends that read `pose_graph_tools_msgs/PoseGraph` (Kimera-Multi, Hydra, ROMAN).",
    ),
    (
        "node.lio_sam_output",
        "On to hand LIO-SAM the stamp pairs of the revisits.",
    ),
    (
        "node.fleet",
        "On in each robot of a fleet (each with its own `node.robot_id`): the nodes share keyframes on \
         `node.fleet_topic` and close loops between robots.",
    ),
];

/// The name with a radar's own name replaced by `<name>` (`radars.front.beta` -> `radars.<name>.beta`).
pub fn generic_name(name: &str) -> String {
    match name.strip_prefix("radars.").and_then(|r| r.split_once('.')) {
        Some((_, field)) => format!("radars.<name>.{field}"),
        None => name.to_string(),
    }
}

/// The tier of a parameter (per-radar parameters as `radars.<name>.field`).
pub fn tier(name: &str) -> Tier {
    if SETUP.contains(&name) {
        Tier::Setup
    } else if TUNING.iter().any(|(n, _)| *n == name) {
        Tier::Tuning
    } else {
        Tier::Internal
    }
}

/// The guidance of a tuning knob (empty for other parameters).
pub fn guidance(name: &str) -> &'static str {
    TUNING
        .iter()
        .find(|(n, _)| *n == name)
        .map_or("", |(_, g)| g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::reference::reference;

    /// At most 40 parameters face users, each one exists, and no name is listed twice.
    #[test]
    fn forty_user_facing_parameters_that_exist() {
        let names: Vec<String> = reference().into_iter().map(|p| p.name).collect();
        let listed: Vec<&str> = SETUP
            .iter()
            .copied()
            .chain(TUNING.iter().map(|(n, _)| *n))
            .collect();
        assert!(
            listed.len() <= 40,
            "{} user-facing parameters",
            listed.len()
        );
        for n in &listed {
            assert!(names.iter().any(|m| m == n), "`{n}` is not a parameter");
            assert_eq!(
                listed.iter().filter(|m| *m == n).count(),
                1,
                "`{n}` listed twice"
            );
        }
        assert!(TUNING.iter().all(|(_, g)| !g.is_empty()));
    }
}
