//! Parameters that change while the node runs (`ros2 param set`): the revisit search and closure gates
//! (`loop.*`), the keyframe spacing (`keyframe.*`) and the node's periods and log level. A change is
//! checked as a start-up value would be (the whole configuration validated with it) and takes effect at
//! the next keyframe; every other parameter shapes the map, the descriptors or the subscriptions and is
//! refused with the reason.

use std::sync::Mutex;

use serde_json::Value;

use super::node::NodeSettings;
use super::{ParamSet, apply};
use dc_loc_core::pipeline::Config;

/// Whether `name` may change at run time.
pub fn is_live(name: &str) -> bool {
    name.starts_with("loop.")
        || name.starts_with("keyframe.")
        || matches!(
            name,
            "node.diagnostics_period"
                | "node.warn_interval"
                | "node.markers_period"
                | "node.keyframe_budget"
                | "node.log_level"
        )
}

/// The parameters in effect, and a checked change waiting for the worker.
#[derive(Debug, Default)]
pub struct LiveParams {
    current: Mutex<ParamSet>,
    pending: Mutex<Option<(Config, NodeSettings)>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl LiveParams {
    /// Live parameters starting from the start-up ones.
    pub fn new(params: &ParamSet) -> Self {
        LiveParams {
            current: Mutex::new(params.clone()),
            pending: Mutex::new(None),
        }
    }

    /// The configuration `name := value` would give, or why it is refused.
    pub fn check(&self, name: &str, value: &Value) -> Result<(Config, NodeSettings), String> {
        if !is_live(name) {
            return Err(format!(
                "`{name}` is read at start-up (it shapes the map, the descriptors or the \
                 subscriptions): restart the node to change it"
            ));
        }
        let mut set = lock(&self.current).clone();
        set.set(name, value.clone());
        let (settings, rest) = NodeSettings::take_from(&set).map_err(|e| e.to_string())?;
        let cfg = apply(&rest).map_err(|e| e.to_string())?;
        Ok((cfg, settings))
    }

    /// Checks and takes `name := value`: the worker applies it at its next step.
    pub fn set(&self, name: &str, value: &Value) -> Result<(), String> {
        let changed = self.check(name, value)?;
        lock(&self.current).set(name, value.clone());
        *lock(&self.pending) = Some(changed);
        log::info!("parameter {name} set to {value}: in effect from the next keyframe");
        Ok(())
    }

    /// The newest accepted change not yet applied.
    pub fn take_pending(&self) -> Option<(Config, NodeSettings)> {
        lock(&self.pending).take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn gates_change_structure_does_not() {
        let live = LiveParams::new(&ParamSet::default());
        assert!(live.check("radars.front.beta", &json!(0.01)).is_err());
        assert!(live.check("map.file", &json!("x")).is_err());
        let e = live.check("loop.search_radius", &json!(-1.0)).unwrap_err();
        assert!(e.contains("loop.search_radius"), "{e}");
        live.set("loop.search_radius", &json!(12.0)).unwrap();
        live.set("node.markers_period", &json!(3.0)).unwrap();
        let (cfg, settings) = live.take_pending().unwrap();
        assert_eq!(cfg.r#loop.search_radius, 12.0, "earlier changes are kept");
        assert_eq!(settings.markers_period, 3.0);
        assert!(live.take_pending().is_none());
    }
}
