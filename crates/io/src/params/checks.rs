//! What a params file or a parameter set leaves to chance, told once at start: a params file none of
//! whose sections applies to the node ([`section_mismatch`]), and radars whose Doppler coupling and
//! noise keep the defaults ([`defaulted_noise`]). Both are warnings, not refusals: ROS 2 itself
//! ignores the sections of other nodes (one file often serves several nodes), and the defaults are a
//! usable radar's values; but either, unnoticed, makes the node run on values the user did not mean.

use serde_json::Value;

use super::{ParamError, ParamSet, fully_qualified, node_key_matches};
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarConfig;

/// The per-radar parameters whose defaults describe one radar model (the ARS408-21).
pub const NOISE_PARAMS: [&str; 4] = ["beta", "sigma_range", "sigma_velocity", "sigma_azimuth"];

/// Why the params file `text` gives node `/namespace/node_name` nothing, or misses a section meant for
/// it: no section applies (`/ns/node`, `node` for `/node`, `/**`, `/**/node`), or a section names the
/// node under another namespace (`dc_loc:` for `/robot1/dc_loc`). `None` when the file applies.
pub fn section_mismatch(
    text: &str,
    namespace: &str,
    node_name: &str,
) -> Result<Option<String>, ParamError> {
    let doc: Value = yaml_serde::from_str(text).map_err(|e| ParamError::Yaml(e.to_string()))?;
    let Value::Object(top) = doc else {
        return Ok(None);
    };
    let fq = fully_qualified(namespace, node_name);
    let sections: Vec<&str> = top.keys().map(String::as_str).collect();
    let matched = sections.iter().any(|k| node_key_matches(k, &fq, node_name));
    let listed = sections
        .iter()
        .map(|k| format!("`{k}`"))
        .collect::<Vec<_>>()
        .join(", ");
    let fix = format!("name a section `{fq}`, `/**/{node_name}` or `/**`");
    if !matched {
        return Ok(Some(format!(
            "no section applies to node `{fq}` (sections: {listed}): its parameters keep their \
             defaults; {fix}"
        )));
    }
    let misplaced: Vec<&str> = sections
        .iter()
        .copied()
        .filter(|k| !node_key_matches(k, &fq, node_name) && last_segment(k) == node_name)
        .collect();
    if misplaced.is_empty() {
        return Ok(None);
    }
    Ok(Some(format!(
        "section {} names node `{node_name}` in another namespace than this node `{fq}` and is not \
         applied; {fix}",
        misplaced
            .iter()
            .map(|k| format!("`{k}`"))
            .collect::<Vec<_>>()
            .join(", ")
    )))
}

fn last_segment(key: &str) -> &str {
    key.trim().rsplit('/').next().unwrap_or_default()
}

/// One warning per radar of `cfg` whose `beta` or noise sigmas ([`NOISE_PARAMS`]) no entry of `set`
/// gives (a params file or an override): naming them, the values they keep and whose they are.
pub fn defaulted_noise(set: &ParamSet, cfg: &Config) -> Vec<String> {
    let d = RadarConfig::default();
    let defaults = format!(
        "beta {} s, sigma_range {} m, sigma_velocity {} m/s, sigma_azimuth {:.2} deg",
        d.beta,
        d.sigma_range,
        d.sigma_velocity,
        d.sigma_azimuth.to_degrees()
    );
    cfg.radar_names
        .iter()
        .filter_map(|radar| {
            let unset: Vec<String> = NOISE_PARAMS
                .iter()
                .map(|p| format!("radars.{radar}.{p}"))
                .filter(|name| !set.entries().iter().any(|(n, _)| n == name))
                .collect();
            (!unset.is_empty()).then(|| {
                format!(
                    "radar `{radar}`: {} not set; the defaults ({defaults}) are a Continental \
                     ARS408-21's (the DC-Loc paper's radar): set your radar's values (docs/robot.md)",
                    unset.join(", ")
                )
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::apply;

    const ROBOT: &str = "
dc_loc:
  ros__parameters:
    body_frame: base_link
";

    #[test]
    fn a_section_for_another_namespace_is_named() {
        assert_eq!(section_mismatch(ROBOT, "/", "dc_loc").unwrap(), None);
        let w = section_mismatch(ROBOT, "/robot1", "dc_loc")
            .unwrap()
            .unwrap();
        assert!(w.contains("node `/robot1/dc_loc`"), "{w}");
        assert!(w.contains("(sections: `dc_loc`)"), "{w}");
        assert!(w.contains("`/**/dc_loc`"), "{w}");
        // A wildcard section applies; the `dc_loc` section beside it still is missed and named.
        let both = format!("/**:\n  ros__parameters:\n    use_sim_time: true\n{ROBOT}");
        let w = section_mismatch(&both, "/robot1", "dc_loc")
            .unwrap()
            .unwrap();
        assert!(w.starts_with("section `dc_loc` names node `dc_loc`"), "{w}");
        for applies in ["/**", "/**/dc_loc", "/robot1/dc_loc"] {
            let text = format!("{applies}:\n  ros__parameters:\n    use_sim_time: true\n");
            assert_eq!(
                section_mismatch(&text, "/robot1", "dc_loc").unwrap(),
                None,
                "{applies}"
            );
        }
        // Sections of other nodes beside one that applies are the usual shared file.
        let shared = format!("{ROBOT}other_node:\n  ros__parameters:\n    x: 1\n");
        assert_eq!(section_mismatch(&shared, "/", "dc_loc").unwrap(), None);
    }

    #[test]
    fn radars_left_at_the_default_noise_are_named() {
        let mut set = ParamSet::default();
        set.set_override("radar_names:=[front, rear]").unwrap();
        for p in NOISE_PARAMS {
            set.set_override(&format!("radars.front.{p}:=0.01"))
                .unwrap();
        }
        set.set_override("radars.rear.beta:=0.005").unwrap();
        let cfg = apply(&set).unwrap();
        let w = defaulted_noise(&set, &cfg);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with(
                "radar `rear`: radars.rear.sigma_range, radars.rear.sigma_velocity, \
                 radars.rear.sigma_azimuth not set"
            ),
            "{w:?}"
        );
        assert!(
            w[0].contains("ARS408-21") && w[0].contains("docs/robot.md"),
            "{w:?}"
        );
        assert!(w[0].contains("sigma_azimuth 0.50 deg"), "{w:?}");
    }
}
