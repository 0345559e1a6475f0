//! A fleet on one world: robots that share the world's seed and drive its loop once each, from evenly
//! spaced starting points, every other robot against the loop's direction, an hour apart, each with
//! detection and odometry noise of its own and an odometry frame at its own start.

use super::config::{LapConfig, SimConfig};
use super::route::Centerline;
use dc_loc_core::validate::ConfigError;

/// Seconds between two robots' starts.
const START_INTERVAL: f64 = 3600.0;

/// The configurations of `robots` robots on `base`'s world: robot `k` starts `k / robots` of the way
/// round the loop, an hour after robot `k - 1`, and drives one lap at the speed of `base`'s lap
/// `k mod laps`, against the loop's direction when `k` is odd.
pub fn fleet(base: &SimConfig, robots: u32) -> Result<Vec<SimConfig>, ConfigError> {
    if !(1..=64).contains(&robots) {
        return Err(ConfigError::new("fleet", "1 to 64 robots"));
    }
    let length = Centerline::new(&base.route)?.length();
    let configs: Vec<SimConfig> = (0..robots)
        .map(|k| {
            let mut c = base.clone();
            c.robot = k;
            c.start_time = base.start_time + START_INTERVAL * f64::from(k);
            c.drive.start = (base.drive.start + length * f64::from(k) / f64::from(robots)) % length;
            c.laps = vec![LapConfig {
                speed: base.laps[k as usize % base.laps.len()].speed,
                reverse: k % 2 == 1,
            }];
            c
        })
        .collect();
    for c in &configs {
        c.validate()?;
    }
    Ok(configs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::simulate;

    /// The robots drive one world from their own starts, each with its own noise.
    #[test]
    fn robots_share_the_world_not_the_noise() {
        let mut base = SimConfig::default();
        base.laps.truncate(1);
        let configs = fleet(&base, 3).unwrap();
        let drives: Vec<_> = configs.iter().map(|c| simulate(c).unwrap()).collect();
        let first = |k: usize| drives[k].ground_truth[0].t_map_body;
        let length = Centerline::new(&base.route).unwrap().length();
        // Robot 1 starts a third of the way round, against the loop's direction (in the lane left of it).
        let line = Centerline::new(&base.route).unwrap();
        let p1 = line.offset_point(length / 3.0, base.world.street.ego_lane_offset());
        assert!((first(1).translation.vector - p1).norm() < 0.5);
        assert!(drives[1].ground_truth[0].lap.reverse && !drives[2].ground_truth[0].lap.reverse);
        // One world: the same walls.
        assert_eq!(
            drives[0].setup.world.walls.len(),
            drives[2].setup.world.walls.len()
        );
        // Robot 0 is the single robot of `base`; the others' noise differs.
        assert_eq!(
            simulate(&base).unwrap().odometry,
            drives[0].odometry,
            "robot 0 is the drive without a fleet"
        );
        let offsets = |k: usize| drives[k].scans[0].scan.detections[0].p_radar;
        assert_ne!(offsets(0), offsets(2));
    }
}
