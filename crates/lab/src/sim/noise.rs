//! The paper's three radar noise models (CARLA experiment) and their sampler.
//!
//! [`NoiseSampler`] draws zero-mean noise for range, azimuth and radial velocity: Gaussian, Student-t or
//! of Gamma shape ([`NoiseModel`]), at the paper's scales ([`NoiseScales`]). docs/algorithm.md, "Noise
//! models", has the paper's numbers and how its `Gamma(0, s)` is read.
//!
//! Entry points: [`NoiseModel`], [`NoiseScales`], [`NoiseConfig`] (with [`NoiseConfig::std_devs`]),
//! [`NoiseSampler`].

use dc_loc_core::validate::{ConfigError, Range, Validator};
use rand::RngExt;
use rand_distr::{Distribution, Gamma, StandardNormal, StudentT};
use serde::{Deserialize, Serialize};

/// Which noise distribution is added to range, azimuth and radial velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseModel {
    /// No noise (geometry tests).
    None,
    /// Zero-mean Gaussian with the `gaussian` standard deviations.
    Gaussian,
    /// Zero-mean shifted Gamma with shape `gamma_shape` and the `gamma` scales (= standard deviations).
    Gamma,
    /// `student_t` scales times a Student-t variate with `student_t_dof` degrees of freedom.
    StudentT,
}

impl NoiseModel {
    /// The model's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            NoiseModel::None => "none",
            NoiseModel::Gaussian => "gaussian",
            NoiseModel::Gamma => "gamma",
            NoiseModel::StudentT => "student-t",
        }
    }
}

/// One value per measured quantity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseScales {
    /// Range, m.
    pub range: f64,
    /// Azimuth, rad.
    pub azimuth: f64,
    /// Radial velocity, m/s.
    pub velocity: f64,
}

impl Default for NoiseScales {
    /// The paper's Gaussian values: 0.25 m, 0.5 deg, 0.1 m/s.
    fn default() -> Self {
        NoiseScales {
            range: 0.25,
            azimuth: 0.5f64.to_radians(),
            velocity: 0.1,
        }
    }
}

impl NoiseScales {
    fn check(&self, v: &mut Validator) {
        v.positive("range", self.range);
        v.positive("azimuth", self.azimuth);
        v.positive("velocity", self.velocity);
    }
}

/// Noise settings shared by all radars.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseConfig {
    /// The model in use (default `gaussian`).
    pub model: NoiseModel,
    /// Gaussian standard deviations (default 0.25 m, 0.5 deg, 0.1 m/s).
    pub gaussian: NoiseScales,
    /// Gamma scales, equal to the standard deviations (default 0.25 m, 0.025 deg, 0.01 m/s, the paper's).
    pub gamma: NoiseScales,
    /// Gamma shape `k` (default 1; skewness `2 / sqrt(k)`).
    pub gamma_shape: f64,
    /// Student-t scales (default 0.25 m, 0.5 deg, 0.1 m/s).
    pub student_t: NoiseScales,
    /// Student-t degrees of freedom (default 100).
    pub student_t_dof: f64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            model: NoiseModel::Gaussian,
            gaussian: NoiseScales::default(),
            gamma: NoiseScales {
                range: 0.25,
                azimuth: 0.025f64.to_radians(),
                velocity: 0.01,
            },
            gamma_shape: 1.0,
            student_t: NoiseScales::default(),
            student_t_dof: 100.0,
        }
    }
}

impl NoiseConfig {
    /// Standard deviations of the selected model (what a pipeline's `sigma_*` should be): the Gaussian
    /// sigmas, the Gamma scales, or the Student-t scales times `sqrt(nu / (nu - 2))`. For `None` the
    /// Gaussian sigmas are returned (a covariance model needs positive values).
    pub fn std_devs(&self) -> NoiseScales {
        match self.model {
            NoiseModel::None | NoiseModel::Gaussian => self.gaussian,
            NoiseModel::Gamma => self.gamma,
            NoiseModel::StudentT => {
                let f = (self.student_t_dof / (self.student_t_dof - 2.0)).sqrt();
                NoiseScales {
                    range: self.student_t.range * f,
                    azimuth: self.student_t.azimuth * f,
                    velocity: self.student_t.velocity * f,
                }
            }
        }
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.section("gaussian", |v| self.gaussian.check(v));
        v.section("gamma", |v| self.gamma.check(v));
        v.section("student_t", |v| self.student_t.check(v));
        v.positive("gamma_shape", self.gamma_shape);
        // Finite variance.
        v.range("student_t_dof", self.student_t_dof, Range::above(2.0));
    }
}

/// Draws `[range, azimuth, velocity]` noise triples for one configuration.
#[derive(Debug, Clone)]
pub struct NoiseSampler {
    kind: Kind,
    scales: NoiseScales,
}

#[derive(Debug, Clone)]
enum Kind {
    None,
    Gaussian,
    Gamma { g: Gamma<f64>, shape: f64 },
    StudentT(StudentT<f64>),
}

impl NoiseSampler {
    /// A sampler for a validated configuration; `ConfigError` if its parameters are unusable.
    pub fn new(cfg: &NoiseConfig) -> Result<Self, ConfigError> {
        let mut v = Validator::at("noise");
        cfg.check(&mut v);
        v.finish()?;
        let (kind, scales) = match cfg.model {
            NoiseModel::None => (Kind::None, cfg.gaussian),
            NoiseModel::Gaussian => (Kind::Gaussian, cfg.gaussian),
            NoiseModel::Gamma => {
                let g = Gamma::new(cfg.gamma_shape, 1.0)
                    .map_err(|e| ConfigError::new("noise.gamma_shape", e.to_string()))?;
                (
                    Kind::Gamma {
                        g,
                        shape: cfg.gamma_shape,
                    },
                    cfg.gamma,
                )
            }
            NoiseModel::StudentT => {
                let t = StudentT::new(cfg.student_t_dof)
                    .map_err(|e| ConfigError::new("noise.student_t_dof", e.to_string()))?;
                (Kind::StudentT(t), cfg.student_t)
            }
        };
        Ok(NoiseSampler { kind, scales })
    }

    /// One zero-mean unit-scale variate of the model.
    fn unit<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        match &self.kind {
            Kind::None => 0.0,
            Kind::Gaussian => rng.sample(StandardNormal),
            Kind::Gamma { g, shape } => (g.sample(rng) - shape) / shape.sqrt(),
            Kind::StudentT(t) => t.sample(rng),
        }
    }

    /// Noise on `[range (m), azimuth (rad), radial velocity (m/s)]`.
    pub fn sample<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> [f64; 3] {
        [
            self.scales.range * self.unit(rng),
            self.scales.azimuth * self.unit(rng),
            self.scales.velocity * self.unit(rng),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    /// Mean, standard deviation and skewness of many samples against the documented values.
    #[test]
    fn each_model_has_its_documented_moments() {
        let n = 200_000;
        for model in [
            NoiseModel::Gaussian,
            NoiseModel::Gamma,
            NoiseModel::StudentT,
        ] {
            let cfg = NoiseConfig {
                model,
                ..NoiseConfig::default()
            };
            let s = NoiseSampler::new(&cfg).unwrap();
            let std = cfg.std_devs();
            let want = [std.range, std.azimuth, std.velocity];
            let mut rng = StdRng::seed_from_u64(7);
            let draws: Vec<[f64; 3]> = (0..n).map(|_| s.sample(&mut rng)).collect();
            for k in 0..3 {
                let m = draws.iter().map(|d| d[k]).sum::<f64>() / n as f64;
                let var = draws.iter().map(|d| (d[k] - m).powi(2)).sum::<f64>() / (n - 1) as f64;
                let sd = var.sqrt();
                let skew = draws.iter().map(|d| ((d[k] - m) / sd).powi(3)).sum::<f64>() / n as f64;
                // Standard error of the mean is sd / sqrt(n) = 0.0022 sd: allow 5 of them.
                assert!(
                    m.abs() < 5.0 * sd / (n as f64).sqrt(),
                    "{model:?} {k}: mean {m}"
                );
                assert!(
                    (sd / want[k] - 1.0).abs() < 0.01,
                    "{model:?} {k}: std {sd} vs {}",
                    want[k]
                );
                let want_skew = if model == NoiseModel::Gamma { 2.0 } else { 0.0 };
                assert!((skew - want_skew).abs() < 0.1, "{model:?} {k}: skew {skew}");
            }
        }
        // The paper's values as documented.
        let c = NoiseConfig::default();
        assert_eq!(c.gaussian.range, 0.25);
        assert!((c.gamma.azimuth.to_degrees() - 0.025).abs() < 1e-12);
        assert!((c.student_t.azimuth.to_degrees() - 0.5).abs() < 1e-12);
        let t = NoiseConfig {
            model: NoiseModel::StudentT,
            ..c
        };
        assert!((t.std_devs().range - 0.25 * (100.0f64 / 98.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn none_is_zero() {
        let s = NoiseSampler::new(&NoiseConfig {
            model: NoiseModel::None,
            ..NoiseConfig::default()
        })
        .unwrap();
        let mut rng = StdRng::seed_from_u64(1);
        assert_eq!(s.sample(&mut rng), [0.0; 3]);
    }
}
