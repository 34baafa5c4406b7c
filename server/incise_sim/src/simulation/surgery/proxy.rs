//! Each tool's proxy in the surgical frame (`incise_tool::proxy`): moved toward its device
//! against the deformed tissue, its touches and its push, and where its inner shape cuts once
//! the push across it passes the tool's threshold.

use super::cut::{self, DeformedGrid};
use super::inside::TissueVolume;
use super::{OrganSurface, ToolRig};
use crate::config::Cutting;
use incise_grid::BranchedGrid;
use incise_math::Vec3;
use incise_math::mat3::{norm, sub};
use incise_mesh::TetTopology;
use incise_tool::proxy::{
    Facet, Obstacles, PENETRATION_TOLERANCE, Push, Reach, Touch, advance, place, push,
    surely_at_least, touches, triangle_gap,
};
use incise_tool::{Pose, Primitive, Shape};

/// How far from the proxy a triangle still counts as touched (m): a few times the contact
/// search's tolerance, so a contact the search left just short is taken, and far below a voxel.
pub(crate) const SKIN: f64 = 2e-5;

/// How far toward the device a stopped proxy is probed for material its cutting shape has not
/// cut (m): beyond the motion's resolution, within the skin.
const UNCUT_PROBE: f64 = 1e-5;

/// The deformed tissue as the proxies see it in one step.
pub(crate) struct TissueView<'a> {
    /// The surface and its deformed vertex positions (by slot).
    pub(crate) surface: &'a OrganSurface,
    pub(crate) positions: &'a [Vec3],
    /// The volume: a branched grid with node positions by grid node id, or tetrahedra with
    /// node positions.
    pub(crate) body: Body<'a>,
}

/// The tissue's volume.
pub(crate) enum Body<'a> {
    Hex { grid: &'a BranchedGrid, by_grid_node: &'a [Vec3] },
    Tet { topology: &'a TetTopology, x: &'a [Vec3] },
}

impl TissueView<'_> {
    /// The triangles that may meet the box `region`.
    fn facets(&self, region: (Vec3, Vec3)) -> Vec<Facet> {
        let mut out = Vec::new();
        self.surface.facets_near(self.positions, region, &mut out);
        out
    }

    /// The part of the volume that may hold a point of `region`.
    fn volume(&self, region: (Vec3, Vec3)) -> TissueVolume<'_> {
        match self.body {
            Body::Hex { grid, by_grid_node } => TissueVolume::hex_near(grid, by_grid_node, region),
            Body::Tet { topology, x } => TissueVolume::tet_near(topology, x, region),
        }
    }
}

/// The box around `shape` at each of `poses`, grown by `by`.
fn region(shape: &Shape, poses: &[&Pose], by: f64) -> (Vec3, Vec3) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for pose in poses {
        let (a, b) = shape.grid_bounds(pose);
        for k in 0..3 {
            lo[k] = lo[k].min(a[k] - by);
            hi[k] = hi[k].max(b[k] + by);
        }
    }
    (lo, hi)
}

/// Whether box `inner` lies within box `outer`.
fn within(inner: (Vec3, Vec3), outer: (Vec3, Vec3)) -> bool {
    (0..3).all(|k| inner.0[k] >= outer.0[k] && inner.1[k] <= outer.1[k])
}

/// Where a tool cuts in a step.
pub(crate) struct Cut {
    /// The pose its inner shape cuts from (a blade's sweep starts there)...
    pub(crate) from: Pose,
    /// ...and the poses it may cut at, nearest first: it cuts at the first that reaches material.
    pub(crate) ahead: Vec<Pose>,
    /// Where its cutting shape presses on the tissue: the triangles, and of each the vertex
    /// nearest the point pressed. The tissue there gives way too.
    pub(crate) pressed: Vec<(Facet, u32)>,
}

/// What one tool's proxy did in the step.
pub(crate) struct ProxyStep {
    /// The triangles around the proxy where it ended.
    pub(crate) facets: Vec<Facet>,
    /// The triangles it touches there.
    pub(crate) touches: Vec<Touch>,
    /// What it pushes the tissue with.
    pub(crate) push: Push,
}

impl ToolRig {
    /// Whether the tool is driven through a proxy (a tool with `contact = "volume"` pushes from
    /// its device's pose by the volume of its mesh's overlap instead).
    pub(crate) fn has_proxy(&self) -> bool {
        self.volume_mesh.is_none()
    }

    /// The pose the tissue feels: the proxy's, or the device's for a tool without a proxy.
    pub(crate) fn felt_pose(&self) -> Option<Pose> {
        if self.has_proxy() { self.proxy } else { self.pose.map(|p| *p.pose()) }
    }

    /// Moves the proxy from `from` toward the device (placing it, when the tool has none yet,
    /// at the device's pose if that touches no tissue), then finds what it touches and pushes.
    /// `None` for a tool without a pose or without a proxy.
    pub(crate) fn step_proxy(
        &mut self,
        view: &TissueView,
        from: Option<Pose>,
        dt: f64,
        embedding: &dyn Fn(u32) -> incise_fem::forcefield::springs::EmbeddedPoint,
    ) -> Option<ProxyStep> {
        let device = *self.pose?.pose();
        if !self.has_proxy() {
            return None;
        }
        self.step_start = from;
        let start = from.unwrap_or(device);
        let swept = region(&self.outer, &[&start, &device], SKIN);
        let mut facets = view.facets(swept);
        let (moved, held_by_uncut);
        {
            // A cutting tool is kept out of its material by what it has not cut; the centre's
            // test, a backstop against a small shape wholly engulfed, would stop a long blade
            // whose middle crosses what a cut left standing beside it.
            let volume = (!self.cuts()).then(|| view.volume(swept));
            let inside = |p: Vec3| volume.as_ref().is_some_and(|v| v.contains(p));
            // A tensor-mass scene's tetrahedra the cutting shape may reach in the step, found
            // once: the test runs at every pose the motion tries.
            let reachable = match (&view.body, &self.inner) {
                (Body::Tet { topology, x }, Some(inner)) if self.cuts() => {
                    cut::tets_near(topology, x, region(inner, &[&start, &device], 0.0))
                }
                _ => Vec::new(),
            };
            // A voxel cutter's voxels, looked up at the first test and kept for the other poses
            // the motion tries (`cut::holds_new_voxels`).
            let voxels = cut::VoxelCache::default();
            let uncut = |a: &Pose, b: &Pose| self.uncut(view, &reachable, &voxels, a, b);
            let cuts = self.cuts();
            let obstacles = Obstacles {
                facets: &facets,
                inside: &inside,
                uncut: cuts.then_some(&uncut as &dyn Fn(&Pose, &Pose) -> bool),
            };
            moved = match from {
                None => place(&self.outer, &device, &obstacles),
                Some(p) => {
                    Some(advance(&self.outer, &p, &device, self.coupling.friction, &obstacles).pose)
                }
            };
            // Held back by material its cutting shape has not cut (a cutting shape that reaches
            // beyond the outer one, which then touches nothing): the coupling presses that
            // shape on the material directly.
            held_by_uncut = cuts
                && moved.is_some_and(|p| {
                    let gap = sub(device.position(), p.position());
                    let len = norm(gap);
                    len > UNCUT_PROBE && {
                        let to = p.with_position(std::array::from_fn(|k| {
                            p.position()[k] + UNCUT_PROBE * gap[k] / len
                        }));
                        uncut(&p, &to)
                    }
                });
        }
        self.proxy = moved;
        let proxy = self.proxy?;
        let here = region(&self.outer, &[&proxy], SKIN);
        if !within(here, swept) {
            facets = view.facets(here);
        }
        let touches = touches(&self.outer, &proxy, &facets, SKIN);
        // What the cut takes (a voxel cut's shape reaches a quarter voxel further than the inner
        // one): the tissue pressed on it is what it cuts.
        let inner = if self.cuts() { self.cutter.as_ref() } else { None };
        let previous = self.previous.as_ref().map(|p| (p, dt));
        let mut push = push(
            &touches,
            &proxy,
            &device,
            previous,
            &self.coupling,
            &self.contact,
            inner,
            embedding,
        );
        if held_by_uncut {
            let gap = sub(device.position(), proxy.position());
            let force = (self.coupling.stiffness * norm(gap)).min(self.coupling.max_force);
            if force > push.across_inner {
                let len = norm(gap);
                push.across_inner = force;
                push.pressing = gap.map(|c| force * c / len);
            }
        }
        Some(ProxyStep { facets, touches, push })
    }

    /// Whether this tool's cutting shape moved from `from` to `to` would be in material it has
    /// not cut ([`incise_tool::proxy::Obstacles::uncut`]).
    /// `reachable`: in a tensor-mass scene, the tetrahedra the cutting shape may reach;
    /// `voxels`: in a voxel scene, the voxels earlier tests of the step looked up.
    fn uncut(
        &self,
        view: &TissueView,
        reachable: &[usize],
        voxels: &cut::VoxelCache,
        from: &Pose,
        to: &Pose,
    ) -> bool {
        let Some(inner) = &self.cutter else { return false };
        match (&view.body, self.spec.cutting) {
            (_, Cutting::Off) => false,
            (Body::Hex { grid, by_grid_node }, Cutting::Remove) => {
                let deformed = DeformedGrid { grid, by_grid_node };
                cut::holds_new_voxels(inner, from, to, &deformed, voxels)
            }
            (Body::Hex { grid, by_grid_node }, Cutting::Separate) => {
                let deformed = DeformedGrid { grid, by_grid_node };
                cut::crosses_linked(inner, from, to, &deformed, view.surface, view.positions)
            }
            (Body::Tet { topology, x }, _) => {
                cut::holds_new_tets(inner, from, to, topology, x, reachable)
            }
        }
    }

    /// Whether the tool cuts at all.
    pub(crate) fn cuts(&self) -> bool {
        self.inner.is_some() && self.spec.cutting != Cutting::Off
    }

    /// Where the tool cuts this step, when it does ([`Cut`]). A proxy's inner shape cuts once
    /// the push across it (`proxy`'s step) reaches the tool's `cut_force`: what it holds one
    /// `step` (a voxel) ahead of where its outer shape touches, along the way it presses the
    /// tissue, or if nothing is
    /// there (the tissue it pressed on was pushed ahead, or a cut's chamfered rim stopped it
    /// short) what it holds a step and a half, two or three ahead; in a tensor-mass scene the
    /// tetrahedra it presses on give way too. A tool without a proxy cuts at its device's pose.
    pub(crate) fn cut(&self, proxy: Option<&ProxyStep>, step: &dyn Fn() -> f64) -> Option<Cut> {
        let inner = self.inner.as_ref().filter(|_| self.cuts())?;
        let device = *self.pose?.pose();
        if !self.has_proxy() {
            let from = self.previous.unwrap_or(device);
            return Some(Cut { from, ahead: vec![device], pressed: Vec::new() });
        }
        let pushed = proxy?;
        let proxy = self.proxy?;
        if pushed.push.across_inner < self.spec.cut_force {
            return None;
        }
        // Along the way the cutting shape presses the tissue (a blade: within its own plane, as
        // it cuts with its edge), not toward the device, which may lie off to a side.
        let mut d = pushed.push.pressing;
        if matches!(inner.primitive(), Some(incise_tool::Primitive::Blade { .. })) {
            let across = proxy.rotate([0.0, 1.0, 0.0]);
            let off: f64 = (0..3).map(|k| d[k] * across[k]).sum();
            d = std::array::from_fn(|k| d[k] - off * across[k]);
        }
        let len = d.iter().map(|c| c * c).sum::<f64>().sqrt();
        if len <= 0.0 {
            return None;
        }
        let dir = d.map(|c| c / len);
        let (lead, step) = (lead(&self.outer, inner, &proxy, dir), step());
        let ahead = [1.0, 1.5, 2.0, 3.0]
            .map(|k| {
                let d = lead + k * step;
                proxy.with_position(std::array::from_fn(|q| proxy.position()[q] + d * dir[q]))
            })
            .to_vec();
        let pressed = pushed
            .push
            .pressed
            .iter()
            .map(|&i| {
                let t = &pushed.touches[i];
                let nearest =
                    (0..3).fold(0, |best, k| if t.bary[k] > t.bary[best] { k } else { best });
                (t.facet, t.facet.vertices[nearest])
            })
            .collect();
        Some(Cut { from: proxy, ahead, pressed })
    }

    /// After a cut this step opened the way: the proxy moves into the space, as far along the
    /// push as the cut reached or the device is, whichever is nearer.
    pub(crate) fn enter_cut(&mut self, at: &Pose) {
        let (Some(proxy), Some(device)) = (self.proxy, self.pose) else { return };
        let d: Vec3 = std::array::from_fn(|k| at.position()[k] - proxy.position()[k]);
        let reach = d.iter().map(|c| c * c).sum::<f64>().sqrt();
        let to_device: Vec3 =
            std::array::from_fn(|k| device.pose().position()[k] - proxy.position()[k]);
        let far = to_device.iter().map(|c| c * c).sum::<f64>().sqrt();
        if reach <= 0.0 {
            return;
        }
        let s = far.min(reach) / reach;
        self.proxy =
            Some(proxy.with_position(std::array::from_fn(|k| proxy.position()[k] + s * d[k])));
    }
}

impl ToolRig {
    /// After the step: tissue that moved toward the proxy where it touched carries it along, so
    /// that a proxy resting on tissue rises with it instead of letting it in. `now` gives a
    /// triangle's corners after the step.
    ///
    /// Each touch asks the proxy to move out along its normal by how far its point moved in;
    /// the proxy moves by their mean, weighted by how far each moved, so tissue closing in from
    /// opposite sides (the walls of a cut on a blade) holds it where it is. Then any triangle
    /// around it (`facets`) that it now overlaps by more than the contact's tolerance (tissue
    /// that turned as it moved, or came from beside it) pushes it out along that triangle's
    /// normal, one after the other. A triangle that overlapped it already is the wall of its
    /// tool's cut or tissue its tool holds, and is left as it is; for a ball or a capsule that
    /// neither cuts nor holds, an overlap can only be tissue that came in, which pushes the
    /// proxy out by what it reaches deeper than when the step began, so that no overlap grows
    /// from step to step.
    pub(crate) fn carry(
        &mut self,
        touches: &[Touch],
        facets: &[Facet],
        now: impl Fn(&[u32; 3]) -> [Vec3; 3],
    ) {
        let Some(proxy) = self.proxy else { return };
        let (mut shift, mut weight) = ([0.0; 3], 0.0);
        for t in touches {
            let corners = now(&t.facet.vertices);
            let p: Vec3 = std::array::from_fn(|k| (0..3).map(|j| t.bary[j] * corners[j][k]).sum());
            // The tool's outward normal points into the tissue: motion against it is toward
            // the proxy.
            let toward = -(0..3).map(|k| (p[k] - t.point[k]) * t.normal[k]).sum::<f64>();
            if toward > 0.0 {
                for k in 0..3 {
                    shift[k] -= toward * toward * t.normal[k];
                }
                weight += toward;
            }
        }
        let mut pose = if weight > 0.0 {
            proxy.with_position(std::array::from_fn(|k| proxy.position()[k] + shift[k] / weight))
        } else {
            proxy
        };
        let reach = Reach::of(&self.outer);
        // Tissue may overlap a proxy for two reasons only: it is the wall of the cut the tool's
        // own blade made, or the tool holds it. Otherwise an overlap is tissue that came in, and
        // it may come no deeper than it was when the step began. That needs the gap exact (a
        // ball's, a capsule's): the branch and bound's gap to a triangle lying flush on a face
        // moves by its sampling from one pose to the next, and the rule would turn that into
        // pushes; such a shape keeps the older rule, an overlap found is left to the penalty.
        let exact = matches!(
            self.outer.primitive(),
            Some(Primitive::Sphere { .. } | Primitive::Capsule { .. })
        );
        let start =
            self.step_start.filter(|_| exact && !self.cuts() && self.grasp.held().is_empty());
        for f in facets {
            // The least gap the triangle may have, and the gap a push leaves it at.
            let (floor, target) = if let Some(start) = start {
                let then = f.corners.map(|p| start.tool_from_grid(p));
                let was = if surely_at_least(&self.outer, &then, -PENETRATION_TOLERANCE, &reach) {
                    0.0
                } else {
                    triangle_gap(&self.outer, &then).distance
                };
                if was >= -PENETRATION_TOLERANCE {
                    (-PENETRATION_TOLERANCE, -0.5 * PENETRATION_TOLERANCE)
                } else {
                    (was - PENETRATION_TOLERANCE, was)
                }
            } else {
                let before = f.corners.map(|p| proxy.tool_from_grid(p));
                if !surely_at_least(&self.outer, &before, -PENETRATION_TOLERANCE, &reach)
                    && triangle_gap(&self.outer, &before).distance < -PENETRATION_TOLERANCE
                {
                    continue;
                }
                (-PENETRATION_TOLERANCE, -0.5 * PENETRATION_TOLERANCE)
            };
            let local = now(&f.vertices).map(|p| pose.tool_from_grid(p));
            if surely_at_least(&self.outer, &local, floor, &reach) {
                continue;
            }
            let g = triangle_gap(&self.outer, &local);
            if g.distance < floor {
                let out = pose.rotate(g.normal);
                let depth = target - g.distance;
                pose = pose
                    .with_position(std::array::from_fn(|k| pose.position()[k] - depth * out[k]));
            }
        }
        self.proxy = Some(pose);
    }
}

/// How far the outer shape reaches beyond the inner one along the grid direction `dir`, at
/// `pose` (m, ≥ 0): the distance between their bounding boxes' supports in that direction.
fn lead(outer: &Shape, inner: &Shape, pose: &Pose, dir: Vec3) -> f64 {
    let local = incise_math::mat3::mul_transpose_vec(pose.matrix(), &dir);
    let support = |s: &Shape| {
        let (lo, hi) = s.bounds();
        (0..3).map(|k| (lo[k] * local[k]).max(hi[k] * local[k])).sum::<f64>()
    };
    (support(outer) - support(inner)).max(0.0)
}
