//! Penalty contact between a tool's outer shape and the organ's surface, and its linearisation
//! for the haptic loop.
//!
//! Every surface point inside the outer shape gets a spring toward the shape's surface along the
//! outward normal: force `k · depth` along `n`, stiffness `k n nᵀ` (an
//! [`EmbeddedSpring`] whose target is the
//! point's projection on the shape's tangent plane), spread to the nodes by the point's
//! embedding. The springs enter the implicit step's matrix, so a stiff contact is as stable as
//! the tissue. Damping along the normal, `c n nᵀ` on the point's velocity relative to the tool's
//! material point there, is part of the same spring and integrated implicitly too: it damps the
//! tissue's motion relative to the moving tool, never against the world (the scene's Rayleigh
//! damping does not apply to the springs; see [`incise_fem::forcefield::springs`]).
//!
//! A per-point stiffness makes a broad contact, which touches many points, stiffer than a
//! narrow one: under the same force a broad tool sinks in less. That is the pressure threshold
//! of paper 1 §3 (Fig. 11): a sharp inner shape reaches the tissue only when the pressure is
//! high enough.
//!
//! A point stays on the side of the shape it entered by. The push direction of a point inside is
//! the shape's nearest-surface normal, except where that normal turned back, by more than 120°,
//! since the last frame (the point went past a box's middle, and the opposite face is now the
//! nearest, or a point carried by a fast tool is nearer the back face): the point is then pushed
//! on along its last direction, to where a ray that way leaves the shape. Without that memory a
//! flat tool pressed more than half its thickness into held tissue would find its face's normals
//! cancel, and a membrane carried by a jump would recoil through the tool. A turn of 90° is left
//! to the nearest normal: a point a blade's edge met is pushed to the blade's nearer side, so the
//! blade slides between the layers it separates instead of ploughing them ahead of its edge.
//!
//! A tool that moves farther than half its thinnest dimension in a frame could jump over a thin
//! membrane. The motion is therefore sampled at sub-poses closer than that, and a point the tool
//! passed over (outside before and after, inside in between) is pushed to the shape's front
//! surface along the motion, with the depth it would have had: the tissue is carried along,
//! not tunnelled through.
//!
//! The force the tissue puts on the tool is the negated sum of the springs' forces, damping
//! included; its
//! derivative with respect to the tool's pose ([`Linearisation`]) follows from the springs'
//! targets moving with the tool: `∂F/∂t = −Σ S`, `∂F/∂θ = Σ S [r]×` (`r` the target's lever about
//! the tool's origin). It leaves out the shape's curvature and the tissue's response within a
//! step, which is what lets a 1 kHz loop evaluate it without a physics step.

use crate::pose::Pose;
use crate::shape::Shape;
use incise_fem::forcefield::springs::{EmbeddedPoint, EmbeddedSpring};
use incise_math::Vec3;
use incise_math::mat3::{Mat3, cross, dot, mul_vec};

/// The scene's contact settings for one tool.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactSettings {
    /// Penalty stiffness per surface point (N/m).
    pub stiffness: f64,
    /// Damping per surface point along the normal (N·s/m).
    pub damping: f64,
}

/// One point in contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactPoint {
    /// The surface vertex.
    pub id: u32,
    /// The outward normal of the tool's shape there (grid frame): the direction the point is pushed.
    pub normal: Vec3,
    /// How far inside the shape it is (m); for a point the tool passed over, the distance to the
    /// shape's front surface along the motion.
    pub depth: f64,
    /// Whether the tool passed over it between the two frames (found by the swept test).
    pub swept: bool,
    /// `normal` in the tool's frame: what the next frame remembers of this point.
    pub local_normal: Vec3,
}

/// The push directions of the points in contact at the last frame, in the tool's frame, by
/// surface vertex: what keeps a point on the side of the shape it entered by.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContactMemory {
    /// `(vertex, direction)`, sorted by vertex.
    directions: Vec<(u32, Vec3)>,
}

impl ContactMemory {
    /// The directions of `contact`'s points.
    #[must_use]
    pub fn of(contact: &Contact) -> Self {
        let mut directions: Vec<(u32, Vec3)> =
            contact.points.iter().map(|c| (c.id, c.local_normal)).collect();
        directions.sort_unstable_by_key(|d| d.0);
        Self { directions }
    }

    /// Every remembered `(vertex, direction)`, sorted by vertex (a snapshot of the state).
    #[must_use]
    pub fn entries(&self) -> &[(u32, Vec3)] {
        &self.directions
    }

    /// A memory from [`Self::entries`].
    ///
    /// # Errors
    /// When the vertices are not strictly ascending.
    pub fn from_entries(directions: Vec<(u32, Vec3)>) -> Result<Self, String> {
        if let Some(w) = directions.windows(2).find(|w| w[0].0 >= w[1].0) {
            return Err(format!(
                "contact memory vertices not ascending ({} then {})",
                w[0].0, w[1].0
            ));
        }
        Ok(Self { directions })
    }

    /// The direction vertex `id` was pushed in at the last frame.
    #[must_use]
    pub fn direction(&self, id: u32) -> Option<Vec3> {
        let i = self.directions.binary_search_by_key(&id, |d| d.0).ok()?;
        Some(self.directions[i].1)
    }

    /// Forgets the vertices `ids` (their slots now hold new vertices).
    pub fn forget(&mut self, ids: &[u32]) {
        if !ids.is_empty() {
            let gone: std::collections::BTreeSet<u32> = ids.iter().copied().collect();
            self.directions.retain(|d| !gone.contains(&d.0));
        }
    }
}

/// The cosine of the largest turn of a point's nearest normal between two frames that is taken
/// as the point moving over the shape rather than through it: 120°.
const PERSIST_COS: f64 = -0.5;

/// The contact of one tool with the surface at one frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Contact {
    /// The points in contact, in surface-vertex order.
    pub points: Vec<ContactPoint>,
    /// Their springs, in the same order.
    pub springs: Vec<EmbeddedSpring>,
}

/// Finds the surface points in contact with `shape` at `pose` and makes their springs.
///
/// `points` are the surface vertices' ids and deformed positions (m, grid frame); `embedding`
/// gives the embedding in the model of those in contact (asked only for the few in contact, so
/// that a large surface is scanned by position alone). `previous` is the tool's pose at the
/// previous frame and `dt` the time between the two (for the swept test and the tool's
/// velocity); `None` on the first frame. `memory` holds the push directions of the last frame's
/// contact. Points are visited in the order given, so the result is deterministic.
#[must_use]
pub fn detect(
    shape: &Shape,
    pose: &Pose,
    previous: Option<(&Pose, f64)>,
    memory: &ContactMemory,
    settings: &ContactSettings,
    points: impl IntoIterator<Item = (u32, Vec3)>,
    embedding: impl Fn(u32) -> EmbeddedPoint,
) -> Contact {
    let (lo, hi) = shape.grid_bounds(pose);
    let sweep = previous.map(|(from, dt)| Sweep::new(shape, from, pose, dt));
    let (lo, hi) = match &sweep {
        Some(s) => {
            let (a, b) = shape.grid_bounds(s.from);
            (std::array::from_fn(|k| lo[k].min(a[k])), std::array::from_fn(|k| hi[k].max(b[k])))
        }
        None => (lo, hi),
    };
    let mut contact = Contact::default();
    for (id, p) in points {
        if (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]) {
            continue;
        }
        let q = pose.tool_from_grid(p);
        let (phi, n_tool) = shape.distance(q);
        let found = if phi < 0.0 {
            let kept = memory
                .direction(id)
                .filter(|last| dot(last, &n_tool) < PERSIST_COS)
                .and_then(|last| shape.exit_along(q, last).map(|depth| (last, depth)));
            let (local, depth) = kept.unwrap_or((n_tool, -phi));
            Some((pose.rotate(local), local, depth, false))
        } else {
            sweep.as_ref().and_then(|s| s.passed_over(shape, pose, p)).map(|(n, d)| {
                let local = mul_vec(&transpose(pose.matrix()), &n);
                (n, local, d, true)
            })
        };
        let Some((normal, local_normal, depth, swept)) = found else { continue };
        let tool_velocity = sweep.as_ref().map_or([0.0; 3], |s| s.velocity_at(pose, p));
        let target = std::array::from_fn(|k| p[k] + depth * normal[k]);
        let spring = EmbeddedSpring::new(embedding(id), outer(normal, settings.stiffness), target)
            .damped(outer(normal, settings.damping), tool_velocity);
        contact.springs.push(spring);
        contact.points.push(ContactPoint { id, normal, depth, swept, local_normal });
    }
    contact
}

/// `k n nᵀ`.
fn outer(n: Vec3, k: f64) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| k * n[r] * n[c]))
}

/// The tool's motion between two frames, sampled finely enough that nothing thinner than the
/// shape slips between two samples.
struct Sweep<'a> {
    from: &'a Pose,
    dt: f64,
    samples: usize,
    /// The shape's bounding-ball centre (tool frame) and radius.
    ball: (Vec3, f64),
    /// How far that centre may stray from the straight line between its two positions.
    slack: f64,
}

/// Most sub-poses a sweep is tested at: a 5 cm jump of a 1 mm blade needs 100.
const MAX_SWEEP_SAMPLES: usize = 256;

impl<'a> Sweep<'a> {
    fn new(shape: &Shape, from: &'a Pose, to: &Pose, dt: f64) -> Self {
        let (lo, hi) = shape.bounds();
        // The farthest any point of the bounding box moves: the corners bound it.
        let mut travel: f64 = 0.0;
        for corner in 0..8 {
            let q = std::array::from_fn(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
            let (a, b) = (from.grid_from_tool(q), to.grid_from_tool(q));
            travel = travel.max((0..3).map(|k| (b[k] - a[k]).powi(2)).sum::<f64>().sqrt());
        }
        let samples = (travel / (0.5 * shape.thinnest())).ceil() as usize;
        let centre: Vec3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
        let radius = 0.5 * (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
        // Between the two poses the centre turns with the rotation: its path leaves the chord by
        // at most its distance from the origin times the angle turned.
        let (a, b) = (from.rotation(), to.rotation());
        let cos_half = (0..4).map(|k| a[k] * b[k]).sum::<f64>().abs().min(1.0);
        let angle = 2.0 * cos_half.acos();
        let slack = dot(&centre, &centre).sqrt() * angle;
        Self {
            from,
            dt,
            samples: samples.clamp(1, MAX_SWEEP_SAMPLES),
            ball: (centre, radius),
            slack,
        }
    }

    /// Whether `p` is farther from the chord between the shape's two centres than the shape
    /// and the path's slack reach: then the tool cannot have passed over it.
    fn out_of_reach(&self, to: &Pose, p: Vec3) -> bool {
        let (a, b) = (self.from.grid_from_tool(self.ball.0), to.grid_from_tool(self.ball.0));
        let ab: Vec3 = std::array::from_fn(|k| b[k] - a[k]);
        let ap: Vec3 = std::array::from_fn(|k| p[k] - a[k]);
        let len2 = dot(&ab, &ab);
        let t = if len2 > 0.0 { (dot(&ap, &ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
        let d: Vec3 = std::array::from_fn(|k| ap[k] - t * ab[k]);
        dot(&d, &d).sqrt() > self.ball.1 + self.slack
    }

    /// The velocity (m/s) of the tool's material point at grid point `p` now.
    fn velocity_at(&self, to: &Pose, p: Vec3) -> Vec3 {
        if self.dt <= 0.0 {
            return [0.0; 3];
        }
        let before = self.from.grid_from_tool(to.tool_from_grid(p));
        std::array::from_fn(|k| (p[k] - before[k]) / self.dt)
    }

    /// For a point outside the shape now: if the tool passed over it since `from` (it was
    /// outside then and inside at some sub-pose), the direction to push it (the motion of the
    /// tool there) and the distance to the shape's front surface along it.
    fn passed_over(&self, shape: &Shape, to: &Pose, p: Vec3) -> Option<(Vec3, f64)> {
        if self.samples < 2
            || self.out_of_reach(to, p)
            || shape.distance(self.from.tool_from_grid(p)).0 < 0.0
        {
            return None;
        }
        let crossed = (1..self.samples).any(|i| {
            let at = self.from.lerp(to, i as f64 / self.samples as f64);
            shape.distance(at.tool_from_grid(p)).0 < 0.0
        });
        if !crossed {
            return None;
        }
        // The tool point that was at p before is now ahead of it: push toward it.
        let ahead = to.grid_from_tool(self.from.tool_from_grid(p));
        let d: Vec3 = std::array::from_fn(|k| ahead[k] - p[k]);
        let len = dot(&d, &d).sqrt();
        if len == 0.0 {
            return None;
        }
        let d = d.map(|c| c / len);
        let local = mul_vec(&transpose(to.matrix()), &d);
        shape.exit_along(to.tool_from_grid(p), local).map(|s| (d, s))
    }
}

fn transpose(m: &Mat3) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| m[c][r]))
}

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
#[allow(clippy::float_cmp, reason = "the normals of axis-aligned faces are exact unit vectors")]
mod tests {
    use super::*;
    use crate::shape::Primitive;

    /// A flat patch of surface points at z = 0, each its own node.
    fn patch(n: usize, spacing: f64) -> Vec<(u32, Vec3)> {
        (0..n * n)
            .map(|i| {
                let position = [
                    (i % n) as f64 * spacing - 0.5 * (n - 1) as f64 * spacing,
                    (i / n) as f64 * spacing - 0.5 * (n - 1) as f64 * spacing,
                    0.0,
                ];
                (i as u32, position)
            })
            .collect()
    }

    /// Points that are each their own node.
    fn still(id: u32) -> EmbeddedPoint {
        EmbeddedPoint::node(id)
    }

    /// The contact of `shape` at `pose` with `points` (each its own node), with no memory.
    fn found(
        shape: &Shape,
        pose: &Pose,
        previous: Option<(&Pose, f64)>,
        points: &[(u32, Vec3)],
    ) -> Contact {
        let memory = ContactMemory::default();
        detect(shape, pose, previous, &memory, &SETTINGS, points.iter().copied(), still)
    }

    fn ball() -> Shape {
        Shape::new(Primitive::Sphere { radius: 0.005 }, [0.0; 3]).unwrap()
    }

    const SETTINGS: ContactSettings = ContactSettings { stiffness: 200.0, damping: 0.0 };

    #[test]
    fn the_force_includes_the_damping_and_its_derivative_in_the_tool_velocity_is_reported() {
        let points = patch(21, 0.001);
        let pose = Pose::at([0.0, 0.0, 0.004]);
        let from = Pose::at([0.0, 0.0, 0.0042]);
        let damped = ContactSettings { stiffness: 200.0, damping: 0.3 };
        let memory = ContactMemory::default();
        let found = |settings: &ContactSettings| {
            detect(
                &ball(),
                &pose,
                Some((&from, 1e-3)),
                &memory,
                settings,
                points.iter().copied(),
                still,
            )
        };
        let (plain, contact) = (found(&SETTINGS), found(&damped));
        let x: Vec<Vec3> = points.iter().map(|p| p.1).collect();
        // The points move down at 0.1 m/s, the tool at 0.2 m/s: it closes on them at 0.1 m/s.
        let v = vec![[0.0, 0.0, -0.1]; x.len()];
        let without = Linearisation::of(&plain.springs, &x, &v, pose.position());
        let with = Linearisation::of(&contact.springs, &x, &v, pose.position());
        // The stiffness part of the pose derivative is the same (the rotation block turns the
        // whole force's lever, damping included).
        for r in 0..6 {
            assert_eq!(without.jacobian[r][..3], with.jacobian[r][..3], "row {r}");
        }
        // The extra force is Σ c n nᵀ (v − w) on the tool: up, against the approach.
        let mut expected = [0.0; 3];
        for (s, c) in contact.springs.iter().zip(&contact.points) {
            let closing = 0.1 * c.normal[2];
            for k in 0..3 {
                expected[k] += 0.3 * c.normal[k] * closing;
            }
            assert!((s.velocity[2] + 0.2).abs() < 1e-9, "the tool's velocity at the point");
        }
        for k in 0..3 {
            assert!((with.force[k] - without.force[k] - expected[k]).abs() < 1e-12);
        }
        assert!(with.force[2] > without.force[2]);
        // ∂F/∂w: a tool 1 mm/s faster into the tissue (δw = −1 mm/s along z) feels D·δw more.
        let faster: Vec<EmbeddedSpring> = contact
            .springs
            .iter()
            .map(|s| EmbeddedSpring { velocity: [0.0, 0.0, s.velocity[2] - 1e-3], ..*s })
            .collect();
        let moved = Linearisation::of(&faster, &x, &v, pose.position());
        for k in 0..3 {
            let predicted = -with.damping[k][2] * 1e-3;
            assert!((moved.force[k] - with.force[k] - predicted).abs() < 1e-12, "{k}");
        }
    }

    #[test]
    fn a_pressed_ball_pushes_the_points_inside_it_along_its_normal() {
        let points = patch(21, 0.001);
        let pose = Pose::at([0.0, 0.0, 0.004]);
        let contact = found(&ball(), &pose, None, &points);
        // The lattice points strictly within √(5² − 4²) = 3 mm of the axis: i² + j² < 9.
        assert_eq!(contact.points.len(), 25);
        let x: Vec<Vec3> = points.iter().map(|p| p.1).collect();
        let lin =
            Linearisation::of(&contact.springs, &x, &vec![[0.0; 3]; x.len()], pose.position());
        // The tissue pushes the tool up (+z), symmetric in x and y.
        assert!(lin.force[2] > 0.0 && lin.force[0].abs() < 1e-12 && lin.force[1].abs() < 1e-12);
        let centre = contact.points.iter().find(|c| c.id == 220).unwrap();
        assert!((centre.depth - 0.001).abs() < 1e-15 && centre.normal == [0.0, 0.0, -1.0]);
    }

    #[test]
    fn the_linearisation_is_the_derivative_of_the_tool_force() {
        // Springs attached to the tool: moving it moves their targets. The extrapolation's error
        // against the force recomputed at the moved pose must fall with the square of the move
        // (a correct first derivative); a wrong Jacobian term leaves a first-order error.
        let points = patch(15, 0.001);
        let q = [0.99, 0.1, 0.05, 0.0f64];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        let pose = Pose::new([0.001, 0.0, 0.0035], q.map(|c| c / norm)).unwrap();
        let contact = found(&ball(), &pose, None, &points);
        assert!(contact.points.len() > 10);
        let x: Vec<Vec3> = points.iter().map(|p| p.1).collect();
        let lin =
            Linearisation::of(&contact.springs, &x, &vec![[0.0; 3]; x.len()], pose.position());
        let error = |eps: f64| {
            let dt = [1e-4 * eps, -5e-5 * eps, 2e-5 * eps];
            let dtheta = [1e-3 * eps, -2e-3 * eps, 5e-4 * eps];
            let moved = pose.moved(dt, dtheta);
            let carried: Vec<EmbeddedSpring> = contact
                .springs
                .iter()
                .map(|s| EmbeddedSpring {
                    target: moved.grid_from_tool(pose.tool_from_grid(s.target)),
                    ..*s
                })
                .collect();
            let exact = Linearisation::of(&carried, &x, &vec![[0.0; 3]; x.len()], moved.position());
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

    #[test]
    fn a_tool_that_jumps_over_a_membrane_carries_it_along() {
        // A 1 mm blade-thin cuboid jumps 5 cm in one frame across a membrane at z = 0.
        let points = patch(11, 0.001);
        let slab =
            Shape::new(Primitive::Cuboid { half_extents: [0.01, 0.01, 0.0005] }, [0.0; 3]).unwrap();
        let from = Pose::at([0.0, 0.0, 0.02]);
        let to = Pose::at([0.0, 0.0, -0.03]);
        let jumped = found(&slab, &to, None, &points);
        assert!(jumped.points.is_empty(), "without the sweep nothing is in contact");
        let swept = found(&slab, &to, Some((&from, 1e-3)), &points);
        assert_eq!(swept.points.len(), points.len());
        for c in &swept.points {
            assert!(c.swept && c.normal == [0.0, 0.0, -1.0]);
            // Pushed to the slab's front (lower) face, 3.05 cm below.
            assert!((c.depth - 0.0305).abs() < 1e-9, "{}", c.depth);
        }
    }
}
