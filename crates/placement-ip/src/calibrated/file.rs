//! A calibrated objective to place with at a junction no validation has seen: the weights
//! `hilo validate --sites` fitted across several junctions, how to predict a rig's mAP from
//! them, and the range of the predictors on the sites they were fitted on, so that a user learns
//! how far their own junction lies from what the fit saw (`calibration.toml`; a study file
//! names it with `calibration_file = "…"`).
//!
//! The prediction is the fit's: mAP = intercept + Σ_f β_f x_f over its features (the
//! objective's terms at the rig), with a 95% interval that adds, as the leave-one-site-out
//! does, the fit's own prediction variance (t_fit · s · √(1 + x̃ᵀ (XᵀX)⁻¹ x̃), x̃ = (1, x)) and the
//! between-site variance (t_sites² · σ_site²): a new junction may sit higher or lower as a whole.
//! Distance: each feature's value in standard deviations of its values over the fitting sites'
//! placements, and whether it lies outside their range; outside it the fit extrapolates.

use super::{Weights, evaluate};
use crate::instance::Instance;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A feature this far from the fitting sites' mean (in their s.d.), or outside their range,
/// makes [`Prediction::advice`] say to validate at the user's own site.
pub const FAR_SD: f64 = 2.0;

/// The file `hilo validate --sites` writes and a study reads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// The sites fitted on (their validations, as given), and each one's profile and commit.
    pub fitted_on: Vec<String>,
    pub validations: Vec<String>,
    /// Which objective this is and why: the fit across sites, or one of its terms alone when that
    /// ranked the held-out sites better on average.
    pub choice: String,
    /// Mean Spearman ρ of this objective with mAP over the held-out sites.
    pub held_out_spearman: f64,
    /// The weights to place with (`[placement] calibration`).
    pub weights: Weights,
    pub prediction: PredictionModel,
    /// Per feature, its values over the fitting sites' placements.
    pub ranges: Vec<FeatureRange>,
}

/// How a rig's mAP is predicted from the objective's terms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PredictionModel {
    pub intercept: f64,
    /// Terms by their study-file names ([`Weights::named`]), and their coefficients.
    pub features: Vec<String>,
    pub coefficients: Vec<f64>,
    /// (XᵀX)⁻¹ of the fit, intercept first.
    pub inverse: Vec<Vec<f64>>,
    pub residual_sd: f64,
    /// 97.5% t quantile of the fit's residual degrees of freedom.
    pub t_fit: f64,
    /// Between-site s.d. the leave-one-site-out measured, and the t quantile of the sites less one.
    pub between_site_sd: f64,
    pub t_sites: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureRange {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub sd: f64,
}

/// A rig's predicted mAP and how far it lies from the fitting sites.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Prediction {
    pub map: f64,
    pub lo: f64,
    pub hi: f64,
    /// The features at the rig.
    pub features: BTreeMap<String, f64>,
    /// The feature farthest from the fitting sites' mean, and by how many of their s.d.
    pub farthest: String,
    pub farthest_sd: f64,
    /// Features outside the fitting sites' range.
    pub outside: Vec<String>,
    pub advice: String,
    /// Per evaluated class, the share of the sampled training traffic's road users of that class
    /// that none of the rig's LiDARs puts a point on (filled in by the caller that has the
    /// traffic; empty where it was not counted). The prediction is of mAP, a mean over classes;
    /// this says what a rig gives up on one class, as at a pole whose blind spot covers a
    /// crosswalk.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub never_hit: BTreeMap<String, f64>,
}

impl CalibrationFile {
    /// Parses and checks a file's text; the error names the field.
    pub fn from_toml(text: &str) -> Result<CalibrationFile, String> {
        let f: CalibrationFile = toml::from_str(text).map_err(|e| e.to_string())?;
        f.check()?;
        Ok(f)
    }

    pub fn to_toml(&self) -> Result<String, String> {
        toml::to_string(self).map_err(|e| e.to_string())
    }

    /// Shapes and values: known feature names, a square (XᵀX)⁻¹ of their number plus one,
    /// finite numbers, non-negative spreads, ranges for every feature.
    pub fn check(&self) -> Result<(), String> {
        self.weights.check().map_err(|e| e.to_string())?;
        let p = &self.prediction;
        let names: Vec<&str> = self.weights.named().iter().map(|(n, _)| *n).collect();
        if let Some(f) = p.features.iter().find(|f| !names.contains(&f.as_str())) {
            return Err(format!("prediction.features: {f:?} is not a term (the terms are {})", names.join(", ")));
        }
        let k = p.features.len();
        if p.coefficients.len() != k {
            return Err(format!("prediction.coefficients: {} for {k} features", p.coefficients.len()));
        }
        if p.inverse.len() != k + 1 || p.inverse.iter().any(|r| r.len() != k + 1) {
            return Err(format!("prediction.inverse: must be {0} × {0} (the features and the intercept)", k + 1));
        }
        let numbers = [p.intercept, p.residual_sd, p.t_fit, p.between_site_sd, p.t_sites];
        if numbers.iter().chain(&p.coefficients).chain(p.inverse.iter().flatten()).any(|v| !v.is_finite())
            || p.residual_sd < 0.0
            || p.between_site_sd < 0.0
        {
            return Err("prediction: every number must be finite, the spreads >= 0".into());
        }
        if let Some(f) = p.features.iter().find(|f| !self.ranges.iter().any(|r| &r.name == *f)) {
            return Err(format!("ranges: no range for feature {f:?}"));
        }
        if let Some(r) = self.ranges.iter().find(|r| !(r.min <= r.mean && r.mean <= r.max && r.sd >= 0.0)) {
            return Err(format!("ranges: {:?} has min {}, mean {}, max {}, sd {}", r.name, r.min, r.mean, r.max, r.sd));
        }
        Ok(())
    }

    /// The prediction for the rig `sel` of `inst` (which holds the road users and point counts
    /// its features need, as placing with [`CalibrationFile::weights`] does).
    pub fn predict(&self, inst: &Instance, sel: &[usize]) -> Prediction {
        let p = &self.prediction;
        let named = Weights::default().named();
        // `check` admits only the objective's own term names.
        let value =
            |f: &str| named.iter().position(|(n, _)| *n == f).map_or(0.0, |k| evaluate(inst, sel, &Weights::unit(k)));
        let x: Vec<f64> = p.features.iter().map(|f| value(f)).collect();
        let row: Vec<f64> = std::iter::once(1.0).chain(x.iter().copied()).collect();
        let map = p.intercept + p.coefficients.iter().zip(&x).map(|(b, v)| b * v).sum::<f64>();
        let leverage: f64 =
            (0..row.len()).map(|a| (0..row.len()).map(|b| row[a] * p.inverse[a][b] * row[b]).sum::<f64>()).sum();
        let own = p.t_fit * p.residual_sd * (1.0 + leverage.max(0.0)).sqrt();
        let half = (own * own + (p.t_sites * p.between_site_sd).powi(2)).sqrt();
        let mut farthest = (String::new(), 0.0f64);
        let mut outside = Vec::new();
        for (f, v) in p.features.iter().zip(&x) {
            let Some(r) = self.ranges.iter().find(|r| &r.name == f) else { continue };
            let z = if r.sd > 0.0 {
                (v - r.mean).abs() / r.sd
            } else if *v == r.mean {
                0.0
            } else {
                f64::INFINITY
            };
            if z > farthest.1 || farthest.0.is_empty() {
                farthest = (f.clone(), z);
            }
            if *v < r.min || *v > r.max {
                outside.push(f.clone());
            }
        }
        let advice = if outside.is_empty() && farthest.1 <= FAR_SD {
            format!(
                "within what the fit saw on {} sites (the farthest feature {:.1} s.d. from their mean)",
                self.fitted_on.len(),
                farthest.1
            )
        } else {
            format!(
                "outside what the fit saw ({}): the prediction extrapolates; run `hilo validate` at this site",
                if outside.is_empty() {
                    format!("{} is {:.1} s.d. from the sites' mean", farthest.0, farthest.1)
                } else {
                    format!("{} beyond the sites' range", outside.join(", "))
                }
            )
        };
        Prediction {
            map,
            lo: map - half,
            hi: map + half,
            features: p.features.iter().cloned().zip(x).collect(),
            farthest: farthest.0,
            farthest_sd: farthest.1,
            outside,
            advice,
            never_hit: BTreeMap::new(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::calibrated::tests::one_lidar_two_targets;

    fn one_term() -> CalibrationFile {
        CalibrationFile {
            fitted_on: vec!["a".into(), "b".into(), "c".into()],
            validations: vec!["quick, 0000000".into(); 3],
            choice: "the fit across sites".into(),
            held_out_spearman: 0.7,
            weights: Weights { lidar: 0.5, ..Weights::default() },
            prediction: PredictionModel {
                intercept: 0.1,
                features: vec!["lidar".into()],
                coefficients: vec![0.5],
                inverse: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
                residual_sd: 0.02,
                t_fit: 2.0,
                between_site_sd: 0.03,
                t_sites: 3.18,
            },
            ranges: vec![FeatureRange { name: "lidar".into(), min: 0.2, max: 0.8, mean: 0.5, sd: 0.1 }],
        }
    }

    /// By hand: mAP 0.1 + 0.5 × 0.75; the interval's two variances; 2.5 s.d. from the sites'
    /// mean, inside their range, so the advice is to validate here.
    #[test]
    fn a_prediction_is_the_fit_and_its_two_variances() {
        let p = one_term().predict(&one_lidar_two_targets(), &[0]);
        assert!((p.features["lidar"] - 0.75).abs() < 1e-6, "{p:?}");
        assert!((p.map - 0.475).abs() < 1e-6, "{p:?}");
        let own = 2.0 * 0.02 * (1.0f64 + 1.0 + 0.75 * 0.75).sqrt();
        let half = (own * own + (3.18f64 * 0.03).powi(2)).sqrt();
        assert!((p.hi - p.map - half).abs() < 1e-6 && (p.map - p.lo - half).abs() < 1e-6, "{p:?}");
        assert!((p.farthest_sd - 2.5).abs() < 1e-5 && p.outside.is_empty(), "{p:?}");
        assert!(p.advice.contains("run `hilo validate`"), "{}", p.advice);
        // Nearer the sites' mean: within what the fit saw.
        let mut f = one_term();
        f.ranges[0].mean = 0.7;
        assert!(f.predict(&one_lidar_two_targets(), &[0]).advice.starts_with("within"));
        // Past the sites' range: said by name.
        f.ranges[0].max = 0.7;
        let p = f.predict(&one_lidar_two_targets(), &[0]);
        assert_eq!(p.outside, vec!["lidar".to_owned()]);
        assert!(p.advice.contains("lidar beyond the sites' range"), "{}", p.advice);
    }

    /// A file round-trips through its TOML, the one hilo ships included; a file that names an
    /// unknown term, has a misshapen matrix or a NaN is refused with the field named.
    #[test]
    fn a_calibration_file_round_trips_and_bad_ones_are_refused() {
        let f = one_term();
        assert_eq!(CalibrationFile::from_toml(&f.to_toml().unwrap()).unwrap(), f);
        let shipped = CalibrationFile::from_toml(include_str!("../../../../fixtures/calibration-sites.toml")).unwrap();
        assert_eq!(CalibrationFile::from_toml(&shipped.to_toml().unwrap()).unwrap(), shipped);
        assert!(shipped.fitted_on.len() >= 4 && shipped.weights.check().is_ok());
        let mut bad = one_term();
        bad.prediction.features = vec!["lidar_sideways".into()];
        assert!(bad.check().unwrap_err().contains("lidar_sideways"));
        let mut bad = one_term();
        bad.prediction.inverse.pop();
        assert!(bad.check().unwrap_err().contains("prediction.inverse"));
        let mut bad = one_term();
        bad.prediction.residual_sd = f64::NAN;
        assert!(bad.check().unwrap_err().contains("finite"));
        let mut bad = one_term();
        bad.ranges.clear();
        assert!(bad.check().unwrap_err().contains("no range"));
        assert!(CalibrationFile::from_toml("fitted_on = 3").is_err());
    }
}
