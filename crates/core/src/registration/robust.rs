//! Robust losses `rho(s)` on a squared normalised residual `s = d^T W d` (paper eq. 10: "a Cauchy robust
//! loss function is also integrated", Barron 2019).
//!
//! Entry points: [`RobustLoss`], [`RobustKind`]; [`RobustLoss::rho`] returns `(rho, rho', rho'')`.
//! Convention (Ceres / Triggs et al. 2000): `rho` acts on the *squared* residual, `rho(s) ~ s` for small
//! `s`, so the cost is `1/2 sum rho(s_i)`. The scale `c` is in units of the residual before squaring
//! (sigma when the residual is whitened), i.e. residuals beyond about `c` start to lose weight.

use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// Which robust loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum RobustKind {
    /// Plain least squares, `rho(s) = s`.
    None,
    /// Cauchy (Lorentzian): `rho(s) = c^2 ln(1 + s / c^2)` (the paper's choice).
    Cauchy,
    /// Huber: `rho(s) = s` for `s <= c^2`, else `2 c sqrt(s) - c^2` (the DC-Loc authors' code).
    Huber,
}

/// A robust loss with its scale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RobustLoss {
    /// The loss function (default `cauchy`, as the paper).
    pub kind: RobustKind,
    /// Scale `c` in units of the unsquared residual (default 3.0: with whitened residuals, a 3-sigma
    /// residual keeps half its weight under Cauchy).
    pub scale: f64,
}

impl Default for RobustLoss {
    fn default() -> Self {
        RobustLoss {
            kind: RobustKind::Cauchy,
            scale: 3.0,
        }
    }
}

impl RobustLoss {
    /// Plain least squares.
    pub fn none() -> Self {
        RobustLoss {
            kind: RobustKind::None,
            scale: 1.0,
        }
    }

    /// `(rho(s), rho'(s), rho''(s))` for a squared residual `s >= 0`.
    #[inline]
    pub fn rho(&self, s: f64) -> (f64, f64, f64) {
        let c2 = self.scale * self.scale;
        match self.kind {
            RobustKind::None => (s, 1.0, 0.0),
            RobustKind::Cauchy => {
                let a = 1.0 + s / c2;
                (c2 * a.ln(), 1.0 / a, -1.0 / (c2 * a * a))
            }
            RobustKind::Huber => {
                if s <= c2 {
                    (s, 1.0, 0.0)
                } else {
                    let r = s.sqrt();
                    (
                        2.0 * self.scale * r - c2,
                        self.scale / r,
                        -0.5 * self.scale / (s * r),
                    )
                }
            }
        }
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("scale", self.scale);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_finite_differences() {
        for kind in [RobustKind::None, RobustKind::Cauchy, RobustKind::Huber] {
            let l = RobustLoss { kind, scale: 1.7 };
            for &s in &[0.01, 0.5, 2.0, 2.8, 3.0, 10.0, 100.0] {
                let h = 1e-5 * (1.0 + s);
                let (r, d1, d2) = l.rho(s);
                let (rp, d1p, _) = l.rho(s + h);
                let (rm, d1m, _) = l.rho(s - h);
                assert!(
                    ((rp - rm) / (2.0 * h) - d1).abs() < 1e-6,
                    "{kind:?} rho' at {s}"
                );
                assert!(
                    ((d1p - d1m) / (2.0 * h) - d2).abs() < 1e-5,
                    "{kind:?} rho'' at {s}"
                );
                assert!(r <= s + 1e-12, "robust losses never exceed least squares");
            }
            // Near zero every loss is least squares.
            let (r, d1, _) = l.rho(1e-9);
            assert!((r - 1e-9).abs() < 1e-15 && (d1 - 1.0).abs() < 1e-6);
        }
    }
}
