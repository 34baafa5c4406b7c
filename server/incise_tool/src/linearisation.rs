//! The force and torque the tissue puts on a tool, and their derivative with respect to the
//! tool's pose, for the haptic loop.
//!
//! The force on the tool is the negated sum of its springs' forces, damping included. The
//! springs' targets move with the tool (the device's pose, through the coupling), so the
//! derivative follows from them: `∂F/∂t = −Σ S`, `∂F/∂θ = Σ S [r]×` (`r` the target's lever
//! about the tool's origin). It leaves out the shape's curvature and the tissue's response
//! within a step, which is what lets a 1 kHz loop evaluate it without a physics step.

use incise_fem::forcefield::springs::EmbeddedSpring;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, cross, mul_vec};

/// The force and torque the tissue puts on a tool, and their derivative with respect to the
/// tool's pose: what the haptic loop evaluates between physics frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearisation {
    /// The tool's origin (m) the torque is taken about.
    pub origin: Vec3,
    /// Force on the tool (N).
    pub force: Vec3,
    /// Torque on the tool about `origin` (N·m).
    pub torque: Vec3,
    /// `∂(force, torque)/∂(translation, rotation)`: rows force x, y, z then torque x, y, z;
    /// columns a translation (m) then a small rotation vector (rad) about `origin`.
    pub jacobian: [[f64; 6]; 6],
    /// `∂force/∂(tool velocity)` (N·s/m): the contact's damping seen by a tool translating
    /// faster or slower than it did (`−Σ C`; the tool's turning rate left out).
    pub damping: Mat3,
}

impl Linearisation {
    /// No contact.
    #[must_use]
    pub fn none(origin: Vec3) -> Self {
        Self {
            origin,
            force: [0.0; 3],
            torque: [0.0; 3],
            jacobian: [[0.0; 6]; 6],
            damping: [[0.0; 3]; 3],
        }
    }

    /// The linearisation of `springs` (all attached to the tool: their targets move with it) at
    /// node positions `x` and velocities `v`, for a tool whose origin is at `origin`.
    #[must_use]
    pub fn of(springs: &[EmbeddedSpring], x: &[Vec3], v: &[Vec3], origin: Vec3) -> Self {
        let mut lin = Self::none(origin);
        for s in springs {
            let p = s.point.position(x);
            // The force on the tool at this spring: S (p − t) + C (ṗ − w).
            let stretch = mul_vec(&s.stiffness, &std::array::from_fn(|k| p[k] - s.target[k]));
            let damping = s.damping_force(v);
            let f: Vec3 = std::array::from_fn(|k| stretch[k] + damping[k]);
            let r: Vec3 = std::array::from_fn(|k| s.target[k] - origin[k]);
            let m = cross(&r, &f);
            let rx = skew(r);
            let fx = skew(f);
            let s_rx = mat_mul(&s.stiffness, &rx);
            let rx_s = mat_mul(&rx, &s.stiffness);
            let rx_s_rx = mat_mul(&rx, &s_rx);
            let fx_rx = mat_mul(&fx, &rx);
            for a in 0..3 {
                lin.force[a] += f[a];
                lin.torque[a] += m[a];
                for b in 0..3 {
                    lin.damping[a][b] -= s.damping[a][b];
                    lin.jacobian[a][b] -= s.stiffness[a][b];
                    lin.jacobian[a][3 + b] += s_rx[a][b];
                    lin.jacobian[3 + a][b] -= rx_s[a][b];
                    lin.jacobian[3 + a][3 + b] += rx_s_rx[a][b] + fx_rx[a][b];
                }
            }
        }
        lin
    }

    /// The linearisation of the penalty of an overlap between the tissue and a rigid tool mesh
    /// (volume contact: `incise_fem::forcefield::volume`), for a tool whose origin is at
    /// `origin`. `tool_gradients` gives each tool vertex's position and `gᵢ = ∂V/∂pᵢ`;
    /// `stiffness` is the penalty's `k_p / A` and `volume` the overlap's volume `V` at the end
    /// of the step (a negative one, past where the linearised overlap closes, pushes nothing).
    ///
    /// The tool's vertices move rigidly with it: a translation `t` and a small rotation `θ`
    /// about the origin change `V` by `Gₜ · t + G_θ · θ`, with `Gₜ = Σ gᵢ` and
    /// `G_θ = Σ (pᵢ − o) × gᵢ`. The force `−(k_p/A) V Gₜ` and the torque `−(k_p/A) V G_θ`
    /// then have the rank-one Jacobian `−(k_p/A) [Gₜ; G_θ][Gₜ; G_θ]ᵀ`: symmetric and
    /// non-positive, so a haptic loop extrapolating with it adds no energy. The change of the
    /// gradients themselves as the tool moves (the volume's second derivative) is left out, as
    /// the field's own linearisation leaves it out. No damping acts on the tool here: the
    /// integrator's Rayleigh term damps the overlap's growth on the tissue's side.
    #[must_use]
    pub fn of_overlap(
        origin: Vec3,
        stiffness: f64,
        volume: f64,
        tool_gradients: impl IntoIterator<Item = (Vec3, Vec3)>,
    ) -> Self {
        let mut g = [0.0; 6];
        for (p, gi) in tool_gradients {
            let r: Vec3 = std::array::from_fn(|k| p[k] - origin[k]);
            let m = cross(&r, &gi);
            for k in 0..3 {
                g[k] += gi[k];
                g[3 + k] += m[k];
            }
        }
        let mut lin = Self::none(origin);
        if volume.is_nan() || volume <= 0.0 {
            return lin;
        }
        let push = stiffness * volume;
        for a in 0..3 {
            lin.force[a] = -push * g[a];
            lin.torque[a] = -push * g[3 + a];
        }
        for (row, ga) in lin.jacobian.iter_mut().zip(g) {
            for (c, gb) in row.iter_mut().zip(g) {
                *c = -stiffness * ga * gb;
            }
        }
        lin
    }

    /// Adds `other`'s force, torque and derivatives (taken about the same origin).
    pub fn add(&mut self, other: &Self) {
        for a in 0..3 {
            self.force[a] += other.force[a];
            self.torque[a] += other.torque[a];
            for b in 0..3 {
                self.damping[a][b] += other.damping[a][b];
            }
        }
        for (row, o) in self.jacobian.iter_mut().zip(&other.jacobian) {
            for (c, oc) in row.iter_mut().zip(o) {
                *c += oc;
            }
        }
    }

    /// The force and torque at the pose moved by translation `dt` (m) and rotation vector
    /// `dtheta` (rad) about the origin, to first order.
    #[must_use]
    pub fn extrapolate(&self, dt: Vec3, dtheta: Vec3) -> (Vec3, Vec3) {
        let d = [dt[0], dt[1], dt[2], dtheta[0], dtheta[1], dtheta[2]];
        let row = |r: usize| (0..6).map(|c| self.jacobian[r][c] * d[c]).sum::<f64>();
        (
            std::array::from_fn(|a| self.force[a] + row(a)),
            std::array::from_fn(|a| self.torque[a] + row(3 + a)),
        )
    }
}

/// `[r]×`, the matrix of `v ↦ r × v`.
fn skew(r: Vec3) -> Mat3 {
    [[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]]
}

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::Pose;
    use incise_fem::forcefield::springs::EmbeddedPoint;
    use incise_math::mat3::mul_vec;

    /// Springs on a patch of points at z = 0 (each its own node), pushed down along tilted
    /// normals by a tool above them: targets up to 0.4 mm below each point.
    fn patch() -> (Vec<EmbeddedSpring>, Vec<Vec3>) {
        let mut springs = Vec::new();
        let mut x = Vec::new();
        for i in 0..25u32 {
            let p = [f64::from(i % 5) * 0.001 - 0.002, f64::from(i / 5) * 0.001 - 0.002, 0.0];
            let len = (p[0] * p[0] + p[1] * p[1] + 0.0001).sqrt();
            let n = [p[0] / len, p[1] / len, -0.01 / len];
            let depth = 0.0004 - 0.05 * (p[0] * p[0] + p[1] * p[1]).sqrt();
            let k = 200.0;
            let s: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| k * n[r] * n[c]));
            let target = std::array::from_fn(|q| p[q] + depth * n[q]);
            springs.push(EmbeddedSpring::new(EmbeddedPoint::node(i), s, target));
            x.push(p);
        }
        (springs, x)
    }

    #[test]
    fn the_force_includes_the_damping_and_its_derivative_in_the_tool_velocity_is_reported() {
        let (plain, x) = patch();
        let damped: Vec<EmbeddedSpring> = plain
            .iter()
            .map(|s| {
                let c: Mat3 = std::array::from_fn(|r| {
                    std::array::from_fn(|q| 0.3 / 200.0 * s.stiffness[r][q])
                });
                s.damped(c, [0.0, 0.0, -0.2])
            })
            .collect();
        // The points move down at 0.1 m/s, the tool at 0.2 m/s: it closes on them at 0.1 m/s.
        let v = vec![[0.0, 0.0, -0.1]; x.len()];
        let origin = [0.0, 0.0, 0.004];
        let without = Linearisation::of(&plain, &x, &v, origin);
        let with = Linearisation::of(&damped, &x, &v, origin);
        for r in 0..6 {
            assert_eq!(without.jacobian[r][..3], with.jacobian[r][..3], "row {r}");
        }
        // The extra force is Σ C (ṗ − w) on the tool.
        let mut expected = [0.0; 3];
        for s in &damped {
            let f = mul_vec(&s.damping, &[0.0, 0.0, 0.1]);
            for k in 0..3 {
                expected[k] += f[k];
            }
        }
        for k in 0..3 {
            assert!((with.force[k] - without.force[k] - expected[k]).abs() < 1e-12);
        }
        // ∂F/∂w: a tool 1 mm/s faster into the tissue (δw = −1 mm/s along z) feels D·δw more.
        let faster: Vec<EmbeddedSpring> = damped
            .iter()
            .map(|s| EmbeddedSpring { velocity: [0.0, 0.0, s.velocity[2] - 1e-3], ..*s })
            .collect();
        let moved = Linearisation::of(&faster, &x, &v, origin);
        for k in 0..3 {
            let predicted = -with.damping[k][2] * 1e-3;
            assert!((moved.force[k] - with.force[k] - predicted).abs() < 1e-12, "{k}");
        }
    }

    #[test]
    fn the_linearisation_is_the_derivative_of_the_tool_force() {
        // Springs attached to the tool: moving it moves their targets. The extrapolation's error
        // against the force recomputed at the moved pose must fall with the square of the move
        // (a correct first derivative); a wrong Jacobian term leaves a first-order error.
        let (springs, x) = patch();
        let q = [0.99, 0.1, 0.05, 0.0f64];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        let pose = Pose::new([0.001, 0.0, 0.0035], q.map(|c| c / norm)).unwrap();
        let still = vec![[0.0; 3]; x.len()];
        let lin = Linearisation::of(&springs, &x, &still, pose.position());
        let error = |eps: f64| {
            let dt = [1e-4 * eps, -5e-5 * eps, 2e-5 * eps];
            let dtheta = [1e-3 * eps, -2e-3 * eps, 5e-4 * eps];
            let moved = pose.moved(dt, dtheta);
            let carried: Vec<EmbeddedSpring> = springs
                .iter()
                .map(|s| EmbeddedSpring {
                    target: moved.grid_from_tool(pose.tool_from_grid(s.target)),
                    ..*s
                })
                .collect();
            let exact = Linearisation::of(&carried, &x, &still, moved.position());
            let (f, m) = lin.extrapolate(dt, dtheta);
            let norm = |v: [f64; 3]| v.iter().map(|c| c * c).sum::<f64>().sqrt();
            let change = norm(std::array::from_fn(|k| exact.force[k] - lin.force[k]))
                + norm(std::array::from_fn(|k| exact.torque[k] - lin.torque[k]));
            let miss = norm(std::array::from_fn(|k| f[k] - exact.force[k]))
                + norm(std::array::from_fn(|k| m[k] - exact.torque[k]));
            (miss, change)
        };
        let (coarse, change) = error(0.1);
        let (fine, _) = error(0.01);
        assert!(coarse / fine > 90.0, "error {coarse:e} → {fine:e}: not second order");
        assert!(coarse < 1e-2 * change, "error {coarse:e} of a change of {change:e}");
    }
}
