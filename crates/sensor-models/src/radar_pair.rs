//! Full ground-plane velocity from two radars.
//!
//! One radar measures a road user's velocity along its line of sight only: v_r = u · v, with u
//! the unit vector from the radar to the detection. A road user moves on the ground (v_z = 0),
//! so two radars at different mounts that see it give two equations in (v_x, v_y):
//!
//! ```text
//! [u_ax u_ay] [v_x]   [v_r,a]
//! [u_bx u_by] [v_y] = [v_r,b]
//! ```
//!
//! solved exactly when the two lines of sight are not parallel on the ground. The error the
//! solution pays is the radial noise times the inverse's gain: with independent radial noise
//! of s.d. σ on both, the velocity's error covariance is σ² (AᵀA)⁻¹, whose root-mean-square
//! over the two components is σ √(trace (AᵀA)⁻¹ / 2); as the angle θ between the ground
//! projections closes, it grows as 1 / sin θ. A pair below `min_angle_rad` is refused, and so is
//! a detection seen from almost straight above (its line of sight has no ground component).
//!
//! Association: a detection of radar A is paired with the nearest detection of radar B on the
//! ground within `max_gap_m` (both on one rigid road user moving without rotation share v;
//! a turning vehicle's points differ by ω × r, a few tenths of a m/s over a car's length).
//!
//! What it leaves out: rotation (yaw rate) of the road user; a vertical velocity; the
//! difference between the two radars' measurement instants (a road user moves ~0.5 m in the
//! 50 ms two unsynchronised radars can be apart, which the association's gap absorbs).

use glam::{Vec2, Vec3};

/// The velocity of one detection pair and what it cost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairVelocity {
    /// Ground-plane velocity, m/s (local frame).
    pub velocity: Vec2,
    /// Angle between the two lines of sight on the ground, rad, in (0, π/2].
    pub angle_rad: f32,
    /// √(trace (AᵀA)⁻¹ / 2): the root-mean-square velocity error per component for unit radial
    /// noise on both radars (1 for perpendicular, level lines of sight).
    pub dilution: f32,
}

/// Why a pair gives no velocity.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum PairError {
    #[error(
        "the two lines of sight meet at {angle_deg:.1} deg on the ground, below the {min_deg:.1} deg asked for: nearly parallel, they cannot tell the velocity across them"
    )]
    Parallel { angle_deg: f32, min_deg: f32 },
    #[error("a line of sight is {from_vertical_deg:.1} deg from vertical: it measures almost no ground velocity")]
    Vertical { from_vertical_deg: f32 },
}

/// The ground velocity that gives radial velocities `vr_a` along `u_a` and `vr_b` along `u_b`
/// (unit lines of sight, radar to detection).
pub fn ground_velocity(
    u_a: Vec3,
    vr_a: f32,
    u_b: Vec3,
    vr_b: f32,
    min_angle_rad: f32,
) -> Result<PairVelocity, PairError> {
    for u in [u_a, u_b] {
        let ground = u.truncate().length();
        if ground < 0.05 {
            return Err(PairError::Vertical { from_vertical_deg: ground.asin().to_degrees() });
        }
    }
    let (ga, gb) = (u_a.truncate(), u_b.truncate());
    let det = ga.perp_dot(gb);
    let sin = (det / (ga.length() * gb.length())).abs().min(1.0);
    let angle = sin.asin();
    if angle < min_angle_rad {
        return Err(PairError::Parallel { angle_deg: angle.to_degrees(), min_deg: min_angle_rad.to_degrees() });
    }
    // Cramer's rule on [ga; gb] v = (vr_a, vr_b).
    let velocity = Vec2::new(vr_a * gb.y - ga.y * vr_b, ga.x * vr_b - vr_a * gb.x) / det;
    // (AᵀA)⁻¹ = A⁻¹ A⁻ᵀ; its trace is the squared Frobenius norm of A⁻¹ = |A|_F² / det².
    let dilution = ((ga.length_squared() + gb.length_squared()) / (det * det) / 2.0).sqrt();
    Ok(PairVelocity { velocity, angle_rad: angle, dilution })
}

/// One radar's detections in the local frame with its position: (position of the radar,
/// detections as (local position, radial velocity)).
pub type RadarView<'a> = (Vec3, &'a [(Vec3, f32)]);

/// Pairs each detection of `a` with the nearest detection of `b` on the ground within
/// `max_gap_m` and solves each pair ([`ground_velocity`]); pairs refused for their geometry are
/// left out. Returns (index in a, index in b, velocity).
pub fn pair_velocities(
    a: RadarView,
    b: RadarView,
    max_gap_m: f32,
    min_angle_rad: f32,
) -> Vec<(usize, usize, PairVelocity)> {
    let mut out = Vec::new();
    for (i, &(p, vr_a)) in a.1.iter().enumerate() {
        let nearest =
            b.1.iter()
                .enumerate()
                .map(|(j, q)| (j, (q.0.truncate() - p.truncate()).length()))
                .filter(|&(_, d)| d <= max_gap_m)
                .min_by(|x, y| x.1.total_cmp(&y.1));
        let Some((j, _)) = nearest else { continue };
        let (q, vr_b) = b.1[j];
        let (u_a, u_b) = ((p - a.0).normalize_or_zero(), (q - b.0).normalize_or_zero());
        if let Ok(v) = ground_velocity(u_a, vr_a, u_b, vr_b, min_angle_rad) {
            out.push((i, j, v));
        }
    }
    out
}
