//! The metric's results as plain text, as `hilo eval` prints them: the per-class table, the
//! range bins, and the bootstrap's intervals and paired differences.

use crate::bootstrap::{BootstrapSummary, MIN_SCENES, PairedSummary};
use crate::{BinMetrics, DetectionMetrics};
use std::fmt::Write;

/// mAP and NDS, then one row per class (AP and the five true-positive errors), then mAP per
/// range bin. `samples` is the number of samples scored.
pub fn metrics_table(m: &DetectionMetrics, bins: &[(String, BinMetrics)], samples: usize) -> String {
    let mut s = format!("mAP {:.4}  NDS {:.4}  ({samples} samples, {:.2} s)\n", m.mean_ap, m.nd_score, m.eval_time);
    let _ = writeln!(s, "{:<12} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}", "class", "AP", "ATE", "ASE", "AOE", "AVE", "AAE");
    for (c, ap) in &m.mean_dist_aps {
        let e = |k: &str| m.label_tp_errors.get(c).and_then(|e| e.get(k)).copied().unwrap_or(f64::NAN);
        let _ = writeln!(
            s,
            "{c:<12} {ap:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3}",
            e("trans_err"),
            e("scale_err"),
            e("orient_err"),
            e("vel_err"),
            e("attr_err")
        );
    }
    for (label, bm) in bins {
        let _ = writeln!(s, "range {label:<10} mAP {:.4}", bm.mean_ap);
    }
    s
}

/// The scene bootstrap's intervals of mAP and NDS, or why there are none.
pub fn bootstrap_line(b: &BootstrapSummary) -> String {
    if b.estimable {
        format!(
            "{:.0}% intervals over {} scenes ({} resamples): mAP [{:.4}, {:.4}], NDS [{:.4}, {:.4}]",
            b.level * 100.0,
            b.scenes,
            b.resamples,
            b.mean_ap.lo,
            b.mean_ap.hi,
            b.nd_score.lo,
            b.nd_score.hi
        )
    } else {
        format!("intervals not estimable: {} scene(s); a scene bootstrap needs at least {MIN_SCENES}", b.scenes)
    }
}

/// The paired difference `b_name − a_name` in mAP and NDS with its interval and P[not better],
/// or the point estimates alone where the scenes are too few.
pub fn paired_line(p: &PairedSummary, b_name: &str, a_name: &str) -> String {
    let (d, n) = (&p.mean_ap_diff, &p.nd_score_diff);
    if p.estimable {
        format!(
            "{b_name} − {a_name}: mAP {:+.4} [{:+.4}, {:+.4}] (P[not better] = {:.3}), NDS {:+.4} [{:+.4}, {:+.4}]",
            d.estimate, d.lo, d.hi, p.p_mean_ap_not_better, n.estimate, n.lo, n.hi
        )
    } else {
        format!(
            "{b_name} − {a_name}: mAP {:+.4}, NDS {:+.4}; interval and P not estimable ({} scene(s); at least \
             {MIN_SCENES} needed)",
            d.estimate, n.estimate, p.scenes
        )
    }
}
