//! Method constants that params files may still name: `dc_loc params --yaml` and the node's
//! parameter dumps list every parameter, and a file written that way names values that are now
//! constants in the code. A name here with the constant's value is accepted (with a warning to remove
//! it); with another value it is refused, since the value cannot take effect.

use dc_loc_core::registration::{correlative, dense, descriptor, ransac};
use serde_json::Value;

use super::ParamError;

/// Names that params files may carry and that nothing reads (any value is accepted).
const UNUSED: &[&str] = &["place.retrieve"];

/// Each constant a params file may name, with its value.
pub fn constants() -> Vec<(&'static str, f64)> {
    use dc_loc_core::registration::constants as r;
    vec![
        ("registration.min_points", r::MIN_POINTS as f64),
        ("registration.reselect_gate", r::RESELECT_GATE),
        ("registration.covariance_scale", r::COVARIANCE_SCALE),
        (
            "registration.screen_ambiguity_translation",
            r::SCREEN_AMBIGUITY_TRANSLATION,
        ),
        (
            "registration.ambiguity_translation",
            ransac::AMBIGUITY_TRANSLATION,
        ),
        (
            "registration.ambiguity_rotation",
            ransac::AMBIGUITY_ROTATION,
        ),
        ("registration.selection_sigma", dense::SELECTION_SIGMA),
        (
            "registration.selection_object_radius",
            dense::SELECTION_OBJECT_RADIUS,
        ),
        (
            "registration.correlative.below_score",
            correlative::BELOW_SCORE,
        ),
        (
            "registration.correlative.rich_below_score",
            correlative::RICH_BELOW_SCORE,
        ),
        (
            "registration.correlative.below_common_view",
            correlative::BELOW_COMMON_VIEW,
        ),
        (
            "registration.correlative.rotation_peaks",
            correlative::ROTATION_PEAKS as f64,
        ),
        (
            "registration.correlative.probes",
            correlative::PROBES as f64,
        ),
        ("registration.correlative.cell", correlative::CELL),
        (
            "registration.correlative.rotation_steps",
            correlative::ROTATION_STEPS as f64,
        ),
        (
            "registration.correlative.rotation_step_deg",
            correlative::ROTATION_STEP_DEG,
        ),
        (
            "registration.correlative.per_rotation",
            correlative::PER_ROTATION as f64,
        ),
        (
            "registration.correlative.candidates",
            correlative::CANDIDATES as f64,
        ),
        (
            "registration.correlative.min_inliers",
            correlative::MIN_INLIERS as f64,
        ),
        (
            "registration.correlative.min_overlap",
            correlative::MIN_OVERLAP,
        ),
        (
            "registration.correlative.covariance_cluster",
            correlative::COVARIANCE_CLUSTER,
        ),
        (
            "registration.correlative.covariance_scale",
            correlative::COVARIANCE_SCALE,
        ),
        ("registration.dense.iterations", dense::ITERATIONS as f64),
        (
            "registration.dense.coarse_rounds",
            dense::COARSE_ROUNDS as f64,
        ),
        ("registration.dense.min_pairs", dense::MIN_PAIRS as f64),
        (
            "registration.dense.covariance_scale",
            dense::COVARIANCE_SCALE,
        ),
        (
            "registration.dense.soft_neighbours",
            dense::SOFT_NEIGHBOURS as f64,
        ),
        (
            "registration.descriptor.angular_weight",
            descriptor::ANGULAR_WEIGHT,
        ),
        (
            "registration.ransac.max_iterations",
            ransac::MAX_ITERATIONS as f64,
        ),
        (
            "registration.ransac.min_sample_separation",
            ransac::MIN_SAMPLE_SEPARATION,
        ),
        (
            "registration.ransac.refit_rounds",
            ransac::REFIT_ROUNDS as f64,
        ),
    ]
}

/// Whether `name` is a constant: `Ok(false)` when it is not, `Ok(true)` when `value` is the
/// constant's (the parameter is to be skipped), an error naming it when the value differs.
pub fn is_constant(name: &str, value: &Value) -> Result<bool, ParamError> {
    if UNUSED.contains(&name) {
        log::warn!("`{name}` has no effect: remove it from the params file");
        return Ok(true);
    }
    let Some((_, constant)) = constants().into_iter().find(|(n, _)| *n == name) else {
        return Ok(false);
    };
    if value.as_f64() == Some(constant) {
        log::warn!(
            "`{name}` is a constant of the method ({constant}), not a parameter: remove it from the params file"
        );
        return Ok(true);
    }
    Err(ParamError::Constant {
        name: name.to_string(),
        value: constant,
        got: value.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{ParamSet, apply, reference::reference};

    #[test]
    fn a_constant_at_its_value_is_skipped_and_at_another_refused() {
        let mut set = ParamSet::default();
        set.set_override("registration.reselect_gate:=3.5").unwrap();
        set.set_override("registration.correlative.probes:=256")
            .unwrap();
        set.set_override("place.retrieve:=7").unwrap();
        assert!(apply(&set).is_ok());
        let mut other = ParamSet::default();
        other
            .set_override("registration.dense.iterations:=3")
            .unwrap();
        let err = apply(&other).unwrap_err();
        assert!(matches!(err, ParamError::Constant { .. }), "{err}");
        assert!(err.to_string().contains("registration.dense.iterations"));
    }

    #[test]
    fn no_constant_is_also_a_parameter() {
        let names: Vec<String> = reference().into_iter().map(|p| p.name).collect();
        for (name, _) in constants() {
            assert!(!names.iter().any(|n| n == name), "{name}");
        }
    }
}
