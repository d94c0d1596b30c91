//! Late fusion: a complete detector per modality — LiDAR (pillar net, backbone, head) and radar
//! (its own pillar net, backbone, head) — trained against the same targets, whose boxes are
//! merged by 3-D IoU matching Ψ ([`merge_late`]: matched pairs fused, position and size weighted
//! towards LiDAR, velocity from radar, scores combined by noisy-OR; unmatched LiDAR boxes kept,
//! unmatched radar boxes kept at half score).

use candle_nn::VarBuilder;
use glam::Vec3;
use hilo_core::{Box3, Detection};
use hilo_fusion::config::TrainConfig;
use hilo_fusion::config::{LIDAR_PILLAR_WIDTH, RADAR_PILLAR_WIDTH};
use hilo_fusion::layout::{At, Layout};
use hilo_fusion::modules::{Backbone, BackboneConfig, Head, PillarNet};
use hilo_fusion::presets::centerpoint;
use hilo_fusion::{DetectorConfig, Fusion, FusionInput, FusionOutput, Preset, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LateConfig {
    pub lidar_channels: usize,
    pub radar_channels: usize,
    /// Backbone of each modality's detector (its out_stride must be the detector's).
    pub backbone: BackboneConfig,
    pub head_channels: usize,
    /// Class channels of each head: the paper's six, or seven with cyclists (the detector sets
    /// it from its own classes when it builds the plugin).
    pub classes: usize,
}

impl Default for LateConfig {
    fn default() -> Self {
        let c = centerpoint();
        LateConfig {
            lidar_channels: 32,
            radar_channels: 16,
            classes: c.classes().len(),
            backbone: c.backbone,
            head_channels: c.head_channels,
        }
    }
}

#[derive(Debug)]
struct Branch {
    pfn: PillarNet,
    backbone: Backbone,
    head: Head,
}

#[derive(Debug)]
pub struct LateFusion {
    lidar: Branch,
    radar: Branch,
    out_stride: usize,
}

fn branch(features: usize, channels: usize, c: &LateConfig, vb: VarBuilder) -> Result<Branch> {
    let pfn = PillarNet::new(features, channels, vb.pp("pfn"))?;
    let backbone = Backbone::new(channels, &c.backbone, vb.pp("backbone"))?;
    let head = Head::new(backbone.out_channels, c.head_channels.max(1), c.classes, c.head_channels > 0, vb.pp("head"))?;
    Ok(Branch { pfn, backbone, head })
}

pub fn build(c: LateConfig, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    Ok(Box::new(LateFusion {
        lidar: branch(LIDAR_PILLAR_WIDTH, c.lidar_channels, &c, vb.pp("lidar"))?,
        radar: branch(RADAR_PILLAR_WIDTH, c.radar_channels, &c, vb.pp("radar"))?,
        out_stride: c.backbone.out_stride,
    }))
}

/// `late`: a CenterPoint-style detector per modality (LiDAR 32 channels, radar 16), boxes
/// merged by 3-D IoU matching.
pub fn late() -> DetectorConfig {
    let base = centerpoint();
    DetectorConfig {
        name: "late".into(),
        input: hilo_fusion::presets::fusion_input(),
        decode: hilo_fusion::presets::fusion_decode(&base.decode),
        fusion: "late".into(),
        fusion_config: serde_json::json!({ "lidar_channels": 32, "radar_channels": 16, "backbone": base.backbone, "head_channels": base.head_channels }),
        ..base
    }
}

/// Registers `late` (plugin and preset).
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("late", Stage::Late, build)?;
    r.add_preset(Preset { detector: late(), train: TrainConfig::default() })
}

fn head_at(layout: &Layout) -> At<'_> {
    match layout {
        Layout::Dense { .. } => At::Dense,
        Layout::Sparse(s) => At::Sparse(&s.head),
    }
}

impl Fusion for LateFusion {
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let mut heads = Vec::new();
        for (b, p) in [(&self.lidar, input.lidar), (&self.radar, input.radar)] {
            let bev = b.pfn.forward(p, input.layout, train)?;
            let x = b.backbone.forward_neck(&bev, input.layout, self.out_stride, train)?;
            heads.push(b.head.forward_neck(&x, head_at(input.layout), train)?);
        }
        Ok(FusionOutput::Heads(heads))
    }

    fn merge(&self, heads: Vec<Vec<Detection>>, max: usize) -> Vec<Detection> {
        let mut it = heads.into_iter();
        let (l, r) = (it.next().unwrap_or_default(), it.next().unwrap_or_default());
        merge_late(&l, &r, max)
    }
}

/// Ψ, late fusion's merge of a LiDAR detector's boxes `l` and a radar detector's boxes `r`:
/// same-class pairs with 3-D IoU ≥ 0.1 are matched greedily by score. A matched pair becomes one
/// box: position and size weighted by score with LiDAR counted twice (it measures shape far
/// better), the radar's velocity (Doppler support), and the noisy-OR of the scores. Unmatched
/// LiDAR boxes are kept as they are; unmatched radar boxes are kept at half their score (radar
/// alone localises coarsely, but may see what LiDAR misses). At most `max` boxes, best first.
pub fn merge_late(l: &[Detection], r: &[Detection], max: usize) -> Vec<Detection> {
    let mut used = vec![false; r.len()];
    let mut out = Vec::with_capacity(l.len() + r.len());
    for a in l {
        let best = r
            .iter()
            .enumerate()
            .filter(|(k, b)| !used[*k] && b.class == a.class)
            .map(|(k, b)| (k, a.box3.iou_3d(&b.box3)))
            .filter(|(_, iou)| *iou >= 0.1)
            .max_by(|x, y| x.1.total_cmp(&y.1).then(y.0.cmp(&x.0)));
        match best {
            Some((k, _)) => {
                used[k] = true;
                let b = &r[k];
                let (wa, wb) = (2.0 * a.score, b.score);
                let mix = |x: f32, y: f32| (wa * x + wb * y) / (wa + wb).max(1e-6);
                let (p, q) = (&a.box3, &b.box3);
                out.push(Detection {
                    box3: Box3::new(
                        Vec3::new(
                            mix(p.center.x, q.center.x),
                            mix(p.center.y, q.center.y),
                            mix(p.center.z, q.center.z),
                        ),
                        mix(p.length_m, q.length_m),
                        mix(p.width_m, q.width_m),
                        mix(p.height_m, q.height_m),
                        if a.score >= b.score { p.yaw } else { q.yaw },
                    ),
                    class: a.class,
                    score: 1.0 - (1.0 - a.score) * (1.0 - b.score),
                    velocity_mps: b.velocity_mps,
                });
            }
            None => out.push(*a),
        }
    }
    for (k, b) in r.iter().enumerate() {
        if !used[k] {
            out.push(Detection { score: 0.5 * b.score, ..*b });
        }
    }
    out.sort_by(|x, y| y.score.total_cmp(&x.score));
    out.truncate(max);
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use glam::Vec2;
    use hilo_core::Class;

    fn det(class: Class, x: f32, score: f32, v: f32) -> Detection {
        Detection {
            box3: Box3::new(Vec3::new(x, 0.0, 0.8), 4.6, 1.9, 1.6, 0.0),
            class,
            score,
            velocity_mps: Vec2::new(v, 0.0),
        }
    }

    #[test]
    fn late_merge_fuses_matches_and_keeps_the_rest_by_rule() {
        let l =
            [det(Class::Car, 0.0, 0.8, 0.0), det(Class::Car, 20.0, 0.6, 0.0), det(Class::Pedestrian, 40.0, 0.5, 0.0)];
        let r = [det(Class::Car, 0.3, 0.5, 7.0), det(Class::Truck, 20.0, 0.9, 1.0), det(Class::Car, -30.0, 0.4, 2.0)];
        let m = merge_late(&l, &r, 10);
        assert_eq!(m.len(), 5);
        // The matched pair: noisy-OR score, LiDAR-weighted position, radar velocity.
        let fused = m.iter().find(|d| (d.score - (1.0 - 0.2 * 0.5)).abs() < 1e-6).unwrap();
        assert!((fused.box3.center.x - (2.0 * 0.8 * 0.0 + 0.5 * 0.3) / (1.6 + 0.5)).abs() < 1e-5);
        assert_eq!(fused.velocity_mps.x, 7.0);
        // A class mismatch is no match; unmatched radar boxes at half score, LiDAR ones as they are.
        assert!(m.iter().any(|d| d.class == Class::Truck && (d.score - 0.45).abs() < 1e-6));
        assert!(m.iter().any(|d| d.class == Class::Car && d.box3.center.x == 20.0 && d.score == 0.6));
        assert!(m.iter().any(|d| d.box3.center.x == -30.0 && (d.score - 0.2).abs() < 1e-6));
        assert!(m.windows(2).all(|w| w[0].score >= w[1].score));
        assert_eq!(merge_late(&l, &r, 2).len(), 2);
    }
}
