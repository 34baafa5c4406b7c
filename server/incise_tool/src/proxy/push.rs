//! How a proxy pushes the tissue it touches: the virtual coupling's spring, shared over the
//! points where the proxy touches the surface's triangles, and a penalty on tissue that overlaps
//! the proxy.
//!
//! **The coupling's share.** The device pulls the proxy with the coupling spring `k_c` (and its
//! damper `b_c`); the proxy, massless and held by the tissue, hands that pull on to the points it
//! touches. Each point `i` (on a triangle, outward normal `nᵢ` of the shape there) is pushed
//! toward where the device's pose would carry it: by `aᵢ = nᵢ · δᵢ − max(gᵢ, 0)`, where `δᵢ` is
//! the displacement of the tool's material point there from the proxy's pose to the device's and
//! `gᵢ` its gap to the proxy. The points share the coupling's stiffness by their weights `wᵢ`
//! (their triangles' areas, faded out across the contact's skin, [`touches`]),
//! `sᵢ = k_c wᵢ / λ`, with `λ` the largest eigenvalue of `Σ wᵢ nᵢ nᵢᵀ`: the contact's
//! stiffness `Σ sᵢ nᵢ nᵢᵀ` is then `k_c` along its stiffest direction, one point or many. The
//! push is limited to the coupling's largest force, the damper's drive with it. A point the
//! device does not push
//! (`aᵢ ≤ 0`) gets no share: the coupling only pushes, and a device pulled back lets go.
//!
//! **The penalty.** Tissue that overlaps the proxy by `−gᵢ > 0` (the walls of the cut a blade
//! made, tissue moved onto a resting tool) is pushed out to the proxy's surface with the tool's
//! per-point stiffness and damping ([`ContactSettings`]), its pushes together held to the
//! coupling's largest force (their targets drawn in toward the tissue by a common factor).
//!
//! Both are linear springs on the contact point, `S = k n nᵀ` with a target along `n` (the
//! shape's tangent plane there), solved implicitly with the tissue. A point on a triangle is the
//! barycentric sum `p = Σ βⱼ pⱼ` of its corners, each embedded in the model; its spring is
//! spread to the corners as springs of stiffness `βⱼ S` whose targets are `pⱼ + (t − p)`: at the
//! step's start they put the point's force `βⱼ S (t − p)` on each corner, and their stiffness
//! `diag(β) ⊗ S` bounds the point spring's `β βᵀ ⊗ S` from above, a contact as stable and a
//! little stiffer across the triangle. Their targets move with the device, so
//! [`crate::Linearisation::of`] gives the haptic loop the coupling's derivative in the pose.

use super::gap::{Reach, surely_at_least, triangle_gap};
use super::motion::{Facet, PENETRATION_TOLERANCE};
use crate::geometry::{at_bary, norm, sub, unit};
use crate::pose::Pose;
use crate::shape::Shape;
use incise_fem::forcefield::springs::{EmbeddedPoint, EmbeddedSpring};
use incise_math::Vec3;
use incise_math::mat3::{Mat3, cross, dot, mul_transpose_vec};

/// The virtual coupling between a device and its proxy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coupling {
    /// The spring between device and proxy (N/m).
    pub stiffness: f64,
    /// Its damper, on the device's velocity relative to the tissue's where the proxy touches it
    /// (N·s/m).
    pub damping: f64,
    /// The largest force it hands the tissue (N).
    pub max_force: f64,
    /// Coulomb friction between the proxy and the tissue (`μ`; 0: the proxy slides freely).
    pub friction: f64,
}

/// The per-point penalty on tissue that overlaps the proxy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactSettings {
    /// Stiffness per point (N/m).
    pub stiffness: f64,
    /// Damping per point along the normal (N·s/m).
    pub damping: f64,
}

/// Where the proxy touches one triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Touch {
    /// The triangle.
    pub facet: Facet,
    /// The triangle's gap to the proxy (m; negative: it overlaps the proxy by that much).
    pub gap: f64,
    /// The touching point's barycentric coordinates.
    pub bary: [f64; 3],
    /// The touching point (m, grid frame).
    pub point: Vec3,
    /// The shape's outward normal there (grid frame): the way the point is pushed.
    pub normal: Vec3,
    /// Its weight in sharing the coupling: the triangle's area, faded out linearly across the
    /// skin (m²).
    pub weight: f64,
}

/// The triangles among `facets` within `skin` (m) of `shape` at `pose`, in `facets`' order.
///
/// A triangle's weight fades from its area at the shape's surface to nothing at `skin`: as the
/// tissue wraps around a pressed proxy its neighbouring triangles come into contact one at a
/// time, and each takes its share of the push gradually instead of all at once.
#[must_use]
pub fn touches(shape: &Shape, pose: &Pose, facets: &[Facet], skin: f64) -> Vec<Touch> {
    let reach = Reach::of(shape);
    facets
        .iter()
        .filter_map(|f| {
            let t = f.corners.map(|p| pose.tool_from_grid(p));
            if surely_at_least(shape, &t, skin, &reach) {
                return None;
            }
            let g = triangle_gap(shape, &t);
            (g.distance < skin).then(|| {
                let [a, b, c] = f.corners;
                let area = 0.5 * norm(cross(&sub(b, a), &sub(c, a)));
                Touch {
                    facet: *f,
                    gap: g.distance,
                    bary: g.bary,
                    point: at_bary(&f.corners, g.bary),
                    normal: pose.rotate(g.normal),
                    weight: area * (1.0 - g.distance.max(0.0) / skin),
                }
            })
        })
        .collect()
}

/// What a proxy's touches put on the tissue in one step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Push {
    /// The springs, on the triangles' corners.
    pub springs: Vec<EmbeddedSpring>,
    /// The force the coupling pushes the tissue with at the step's start (N).
    pub coupling_force: Vec3,
    /// The part of it pushed through points behind which the tool's inner shape lies: the force
    /// across the cutting shape (N, its magnitude along the points' normals).
    pub across_inner: f64,
    /// Of those points, the ones the device carries into the tissue rather than along it
    /// (within 60° of their normal): indices into the touches, ascending. The tissue there is
    /// what the cutting shape presses on.
    pub pressed: Vec<usize>,
    /// The sum of the pushes through those points (N): the way the cutting shape presses.
    pub pressing: Vec3,
}

/// The springs of `touches` for a proxy at `proxy` coupled to a device at `device` (which was at
/// `previous` the step before, `dt` earlier: the device's velocity). `inner` is the tool's
/// cutting shape, if it has one; `embedding` gives a surface vertex's embedding in the model.
#[must_use]
#[allow(clippy::too_many_arguments, reason = "the step's poses and the tool's three settings")]
pub fn push(
    touches: &[Touch],
    proxy: &Pose,
    device: &Pose,
    previous: Option<(&Pose, f64)>,
    coupling: &Coupling,
    penalty: &ContactSettings,
    inner: Option<&Shape>,
    embedding: impl Fn(u32) -> EmbeddedPoint,
) -> Push {
    // How far the device's pose carries each touching point past the proxy's surface, and
    // whether the carry is mostly into the tissue there (not along it: a blade's walls).
    let carries: Vec<(f64, bool)> = touches
        .iter()
        .map(|t| {
            let d = sub(device.grid_from_tool(proxy.tool_from_grid(t.point)), t.point);
            let into = dot(&t.normal, &d);
            ((into - t.gap.max(0.0)).max(0.0), into > 0.5 * norm(d))
        })
        .collect();
    let pushed: Vec<f64> = carries.iter().map(|c| c.0).collect();
    let shares = shares(touches, &pushed, coupling.stiffness);
    let mut force = [0.0; 3];
    for ((t, &a), &s) in touches.iter().zip(&pushed).zip(&shares) {
        for k in 0..3 {
            force[k] += s * a * t.normal[k];
        }
    }
    let scale = match norm(force) {
        f if f > coupling.max_force => coupling.max_force / f,
        _ => 1.0,
    };
    let mut out = Push { coupling_force: force.map(|c| c * scale), ..Push::default() };
    // The damper drives the tissue toward the device's velocity; a device that jumps (a jab,
    // a dropped stylus) would make that any force at all. Its push is held to what the spring
    // leaves of the largest force.
    let room = (coupling.max_force - norm(out.coupling_force)).max(0.0);
    let fastest = if coupling.damping > 0.0 { room / coupling.damping } else { 0.0 };
    // The penalty, too, pushes with no more than the largest force in all: a cut's walls that
    // start deep in the tool are eased out over several steps instead of thrown.
    let overlap_of = |t: &Touch| if -t.gap > PENETRATION_TOLERANCE { -t.gap } else { 0.0 };
    let thrust: f64 = touches.iter().map(|t| penalty.stiffness * overlap_of(t)).sum();
    let ease = if thrust > coupling.max_force { coupling.max_force / thrust } else { 1.0 };
    for (i, ((t, &a), &s)) in touches.iter().zip(&pushed).zip(&shares).enumerate() {
        let a = a * scale;
        // Within the contact's tolerance the tissue touches the proxy; beyond it, it overlaps.
        let overlap = ease * overlap_of(t);
        let (mut k, mut ka, mut c) = (0.0, 0.0, 0.0);
        if a > 0.0 {
            (k, ka) = (s, s * a);
            c = coupling.damping * s / coupling.stiffness;
            if let Some(inner) = inner
                && behind(inner, proxy, t)
            {
                out.across_inner += s * a;
                if carries[i].1 {
                    out.pressed.push(i);
                    for k in 0..3 {
                        out.pressing[k] += s * a * t.normal[k];
                    }
                }
            }
        }
        if overlap > 0.0 {
            k += penalty.stiffness;
            ka += penalty.stiffness * overlap;
            c += penalty.damping;
        }
        if k <= 0.0 {
            continue;
        }
        let n = t.normal;
        let depth = ka / k;
        let lift: Vec3 = n.map(|c| c * depth);
        let velocity = previous.map_or([0.0; 3], |(before, dt)| {
            let was = before.grid_from_tool(device.tool_from_grid(t.point));
            if dt > 0.0 { std::array::from_fn(|k| (t.point[k] - was[k]) / dt) } else { [0.0; 3] }
        });
        let speed = norm(velocity);
        let velocity =
            if speed > fastest { velocity.map(|c| c * fastest / speed) } else { velocity };
        for (j, &beta) in t.bary.iter().enumerate() {
            if beta <= 0.0 {
                continue;
            }
            let corner = t.facet.corners[j];
            let target = std::array::from_fn(|q| corner[q] + lift[q]);
            out.springs.push(
                EmbeddedSpring::new(embedding(t.facet.vertices[j]), outer(n, beta * k), target)
                    .damped(outer(n, beta * c), velocity),
            );
        }
    }
    out
}

/// Each touch's share of the coupling's stiffness (module doc); 0 for those not pushed.
fn shares(touches: &[Touch], pushed: &[f64], stiffness: f64) -> Vec<f64> {
    let weights: Vec<f64> =
        touches.iter().zip(pushed).map(|(t, &a)| if a > 0.0 { t.weight } else { 0.0 }).collect();
    let mut m = [[0.0; 3]; 3];
    let mut mean = [0.0; 3];
    for (t, &w) in touches.iter().zip(&weights) {
        for r in 0..3 {
            mean[r] += w * t.normal[r];
            for c in 0..3 {
                m[r][c] += w * t.normal[r] * t.normal[c];
            }
        }
    }
    let lambda = largest_eigenvalue(&m, mean);
    if lambda <= 0.0 {
        return vec![0.0; touches.len()];
    }
    weights.iter().map(|w| stiffness * w / lambda).collect()
}

/// The largest eigenvalue of the symmetric positive semi-definite `m`, by power iteration from
/// `start` (the weighted mean normal, near the answer for a contact patch).
fn largest_eigenvalue(m: &Mat3, start: Vec3) -> f64 {
    let trace = m[0][0] + m[1][1] + m[2][2];
    if trace <= 0.0 {
        return 0.0;
    }
    let mut v = if norm(start) > 1e-9 * trace {
        unit(start)
    } else {
        [1.0, 1.0, 1.0].map(|c: f64| c / 3f64.sqrt())
    };
    let mut lambda = 0.0;
    for _ in 0..32 {
        let w = incise_math::mat3::mul_vec(m, &v);
        let len = norm(w);
        if len <= 0.0 {
            break;
        }
        lambda = dot(&v, &w);
        v = w.map(|c| c / len);
    }
    // The Rayleigh quotient approaches the largest eigenvalue from below; the trace bounds it
    // from above, and at most a third of the trace lies below it.
    lambda.max(trace / 3.0)
}

/// Whether the tool's inner shape lies behind the touching point, on the ray from it into the
/// tool against the normal, and faces it with its cutting part: a blade cuts within its own
/// plane, with its edge (its `−z`) and its ends (`±x`), not with its flat sides (the point
/// pushed within 60° of `±y`) nor its spine (within 60° of `+z`).
fn behind(inner: &Shape, proxy: &Pose, t: &Touch) -> bool {
    let d = mul_transpose_vec(proxy.matrix(), &t.normal).map(|c| -c);
    // Not the spine: a blade lifted out of its cut would cut its way up.
    if matches!(inner.primitive(), Some(crate::shape::Primitive::Blade { .. }))
        && (d[1].abs() > 0.5 || d[2] < -0.5)
    {
        return false;
    }
    inner.ray_meets(proxy.tool_from_grid(t.point), d)
}

/// `k n nᵀ`.
fn outer(n: Vec3, k: f64) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| k * n[r] * n[c]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::Primitive;

    /// Triangles of a flat floor at z = 0 around the origin, each vertex its own node.
    fn floor() -> Vec<Facet> {
        let p = |i: i32, j: i32| [f64::from(i) * 0.002, f64::from(j) * 0.002, 0.0];
        let mut facets = Vec::new();
        let mut id = 0;
        for i in -3..3 {
            for j in -3..3 {
                let v = |a: i32, b: i32| ((a + 10) * 100 + b + 10) as u32;
                facets.push(Facet {
                    id,
                    vertices: [v(i, j), v(i + 1, j), v(i + 1, j + 1)],
                    corners: [p(i, j), p(i + 1, j), p(i + 1, j + 1)],
                });
                facets.push(Facet {
                    id: id + 1,
                    vertices: [v(i, j), v(i + 1, j + 1), v(i, j + 1)],
                    corners: [p(i, j), p(i + 1, j + 1), p(i, j + 1)],
                });
                id += 2;
            }
        }
        facets
    }

    const COUPLING: Coupling =
        Coupling { stiffness: 1000.0, damping: 0.0, max_force: 8.0, friction: 0.0 };
    const PENALTY: ContactSettings = ContactSettings { stiffness: 500.0, damping: 0.0 };

    #[test]
    fn a_flat_face_on_a_floor_pushes_it_with_the_coupling_alone() {
        // A 6 mm box face resting on the floor, the device 2 mm below: the
        // push is the coupling's, 1000 N/m × 2 mm = 2 N down, however many triangles it touches.
        let box_ = Shape::new(Primitive::Cuboid { half_extents: [0.003, 0.003, 0.001] }, [0.0; 3])
            .unwrap();
        let proxy = Pose::at([0.0001, 0.0002, 0.001]);
        let device = Pose::at([0.0001, 0.0002, -0.001]);
        let facets = floor();
        let found = touches(&box_, &proxy, &facets, 1e-5);
        assert!(found.len() > 10, "{}", found.len());
        let p = push(&found, &proxy, &device, None, &COUPLING, &PENALTY, None, EmbeddedPoint::node);
        assert!((p.coupling_force[2] + 2.0).abs() < 1e-6, "{:?}", p.coupling_force);
        // The springs' forces at the step's start are that push.
        let x = |v: u32| {
            let (a, b) = ((v / 100) as i32 - 10, (v % 100) as i32 - 10);
            [f64::from(a) * 0.002, f64::from(b) * 0.002, 0.0]
        };
        let mut total = [0.0; 3];
        for s in &p.springs {
            let at = x(s.point.nodes[0]);
            let f = incise_math::mat3::mul_vec(&s.stiffness, &sub(s.target, at));
            for k in 0..3 {
                total[k] += f[k];
            }
        }
        assert!((total[2] + 2.0).abs() < 1e-6, "{total:?}");
    }

    #[test]
    #[allow(clippy::float_cmp, reason = "no push is exactly zero")]
    fn the_push_is_limited_to_the_couplings_largest_force_and_a_pulled_device_lets_go() {
        let ball = Shape::new(Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap();
        let proxy = Pose::at([0.0003, 0.0001, 0.001]);
        let facets = floor();
        let found = touches(&ball, &proxy, &facets, 1e-5);
        assert!(!found.is_empty());
        let deep = Pose::at([0.0003, 0.0001, -0.05]);
        let p = push(&found, &proxy, &deep, None, &COUPLING, &PENALTY, None, EmbeddedPoint::node);
        assert!((norm(p.coupling_force) - 8.0).abs() < 1e-9, "{:?}", p.coupling_force);
        let lifted = Pose::at([0.0003, 0.0001, 0.003]);
        let p = push(&found, &proxy, &lifted, None, &COUPLING, &PENALTY, None, EmbeddedPoint::node);
        assert!(p.springs.is_empty() && p.coupling_force == [0.0; 3]);
    }

    #[test]
    #[allow(clippy::float_cmp, reason = "no push is exactly zero")]
    fn tissue_overlapping_the_proxy_is_pushed_out_by_the_penalty() {
        let ball = Shape::new(Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap();
        // 0.4 mm into the floor, the device at the proxy: no coupling push, only the penalty.
        let proxy = Pose::at([0.0003, 0.0001, 0.0006]);
        let facets = floor();
        let found = touches(&ball, &proxy, &facets, 1e-5);
        let p = push(&found, &proxy, &proxy, None, &COUPLING, &PENALTY, None, EmbeddedPoint::node);
        assert_eq!(p.coupling_force, [0.0; 3]);
        assert!(!p.springs.is_empty());
        for s in &p.springs {
            assert!(s.target[2] < 0.0 && (s.stiffness[2][2] - 500.0 * 1.0).abs() < 500.0);
        }
    }

    #[test]
    fn the_force_across_the_inner_shape_counts_only_the_points_in_front_of_it() {
        // A broad box (12 mm) with a 2 mm wide blade inside: of the 2 N push, about the part of
        // the face over the blade goes across it.
        let outer = Shape::new(
            Primitive::Cuboid { half_extents: [0.006, 0.006, 0.002] },
            [0.0, 0.0, 0.002],
        )
        .unwrap();
        let inner = Shape::new(
            Primitive::Blade { length: 0.012, height: 0.003, thickness: 0.002 },
            [0.0, 0.0, 0.0005],
        )
        .unwrap();
        let proxy = Pose::at([0.0, 0.0, 1e-7]);
        let device = Pose::at([0.0, 0.0, -0.002]);
        let facets = floor();
        let found = touches(&outer, &proxy, &facets, 1e-5);
        let p = push(
            &found,
            &proxy,
            &device,
            None,
            &COUPLING,
            &PENALTY,
            Some(&inner),
            EmbeddedPoint::node,
        );
        let total = norm(p.coupling_force);
        assert!(
            p.across_inner > 0.0 && p.across_inner < 0.6 * total,
            "{} of {total}",
            p.across_inner
        );
    }
}
