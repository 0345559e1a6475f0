//! Scan stamps from a radar's trigger (`radars.<name>.trigger_topic`).
//!
//! Some radar drivers stamp their clouds with zero or with the host's clock while the rest of the robot
//! (the IMU above all) runs on the sensor platform's clock; the platform then publishes a
//! `std_msgs/Header` at the start of each radar frame on a trigger topic (the rio datasets do). A
//! radar's cloud is published after its frame is measured and processed, before the next frame
//! starts, so each cloud belongs to the newest trigger that arrived before it: the cloud takes that
//! trigger's stamp plus `radars.<name>.trigger_delay` (the time from the trigger to the instant the
//! scan stands for, e.g. half the frame's chirp time). A cloud with no trigger since the previous
//! cloud of its radar is refused: it cannot be placed in time.

use crate::math::Stamp;

/// Why a cloud has no stamp from its trigger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TriggerError {
    /// No trigger has arrived yet.
    #[error("no trigger has arrived before this scan")]
    NoneYet,
    /// The newest trigger already stamped the previous scan.
    #[error("no trigger since the previous scan (the newest one already stamped it)")]
    Used,
}

/// The newest trigger of each radar that has a trigger topic, and whether a scan took it.
#[derive(Debug, Clone)]
pub struct TriggerStamps {
    /// Per radar (index in `radar_names`): its trigger delay, s, when it has a trigger topic.
    delays: Vec<Option<f64>>,
    /// Per radar: the newest trigger's stamp and whether a scan took it.
    newest: Vec<Option<(Stamp, bool)>>,
}

impl TriggerStamps {
    /// Stamps for radars with these delays (`None`: the radar has no trigger topic and keeps its own
    /// stamps).
    pub fn new(delays: Vec<Option<f64>>) -> Self {
        let newest = vec![None; delays.len()];
        TriggerStamps { delays, newest }
    }

    /// Whether radar `radar` takes its stamps from a trigger.
    pub fn triggered(&self, radar: usize) -> bool {
        matches!(self.delays.get(radar), Some(Some(_)))
    }

    /// A trigger of radar `radar` at `stamp` (ignored for a radar without a trigger topic).
    pub fn trigger(&mut self, radar: usize, stamp: Stamp) {
        if self.triggered(radar) {
            self.newest[radar] = Some((stamp, false));
        }
    }

    /// The stamp of a scan of radar `radar` that arrives now: `own` for a radar without a trigger
    /// topic, else its newest trigger's stamp plus the delay (the trigger is then used up).
    pub fn stamp(&mut self, radar: usize, own: Stamp) -> Result<Stamp, TriggerError> {
        let Some(Some(delay)) = self.delays.get(radar).copied() else {
            return Ok(own);
        };
        match &mut self.newest[radar] {
            None => Err(TriggerError::NoneYet),
            Some((_, true)) => Err(TriggerError::Used),
            Some((stamp, used)) => {
                *used = true;
                Ok(Stamp(stamp.0 + Stamp::from_secs_f64(delay).0))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scan_takes_the_newest_trigger_once() {
        let mut t = TriggerStamps::new(vec![None, Some(0.01)]);
        assert_eq!(t.stamp(0, Stamp(7)), Ok(Stamp(7)));
        assert_eq!(t.stamp(1, Stamp(7)), Err(TriggerError::NoneYet));
        t.trigger(1, Stamp(1_000_000_000));
        t.trigger(1, Stamp(1_100_000_000));
        assert_eq!(t.stamp(1, Stamp(0)), Ok(Stamp(1_110_000_000)));
        assert_eq!(t.stamp(1, Stamp(0)), Err(TriggerError::Used));
        t.trigger(0, Stamp(5));
        assert_eq!(t.stamp(0, Stamp(9)), Ok(Stamp(9)));
    }
}
