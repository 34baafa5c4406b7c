//! A tool's shapes, in the tool frame: analytic primitives given by their signed distance.
//!
//! Contact needs, for a point, how deep it is inside a shape and which way is out: the signed
//! distance `φ` (negative inside) and its gradient, the outward unit normal. The primitives
//! here have both in closed form. Conventions follow a laparoscopic instrument: the tip at the
//! tool frame's origin, the shaft along `+z`; each shape may be offset within the frame, so an
//! inner (cutting) shape sits where the blade's edge is inside the outer (repulsion) shape.

use crate::mesh_shape::MeshShape;
use incise_math::Vec3;
use std::sync::Arc;

/// An analytic primitive in its own frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Primitive {
    /// A ball of `radius` (m) about the origin.
    Sphere {
        /// Radius (m).
        radius: f64,
    },
    /// The points within `radius` of the segment from the origin to `(0, 0, length)`: a rounded
    /// shaft whose tip is at the origin.
    Capsule {
        /// Radius (m).
        radius: f64,
        /// Length of the axis (m).
        length: f64,
    },
    /// An axis-aligned box about the origin.
    Cuboid {
        /// Half the edge lengths (m).
        half_extents: Vec3,
    },
    /// A flat blade: a box `length` along x, `thickness` along y, `height` along z, whose cutting
    /// edge is the segment at `z = 0` (it rises along `+z` from its edge); its mid-plane `y = 0`
    /// is the surface that separates in separation mode.
    Blade {
        /// Edge length (m).
        length: f64,
        /// Height above the edge (m).
        height: f64,
        /// Thickness (m).
        thickness: f64,
    },
}

/// Why a shape was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{what}")]
pub struct ShapeError {
    /// What is wrong.
    pub what: String,
}

/// What a shape is made of.
#[derive(Clone, Debug, PartialEq)]
enum Kind {
    Primitive(Primitive),
    Mesh(Arc<MeshShape>),
}

/// A primitive or a closed mesh placed in the tool frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Shape {
    kind: Kind,
    /// Where the primitive's (or the mesh's) origin is in the tool frame (m).
    offset: Vec3,
}

impl Shape {
    /// `primitive` with its origin at `offset` in the tool frame; every size must be finite and
    /// positive.
    pub fn new(primitive: Primitive, offset: Vec3) -> Result<Self, ShapeError> {
        let sizes: Vec<(&str, f64)> = match primitive {
            Primitive::Sphere { radius } => vec![("radius", radius)],
            Primitive::Capsule { radius, length } => vec![("radius", radius), ("length", length)],
            Primitive::Cuboid { half_extents } => {
                half_extents.iter().map(|&h| ("half extent", h)).collect()
            }
            Primitive::Blade { length, height, thickness } => {
                vec![("length", length), ("height", height), ("thickness", thickness)]
            }
        };
        for (name, value) in sizes {
            if !(value.is_finite() && value > 0.0) {
                return Err(ShapeError {
                    what: format!("{name} is {value}; it must be a finite length > 0 m"),
                });
            }
        }
        if !offset.iter().all(|c| c.is_finite()) {
            return Err(ShapeError { what: format!("offset {offset:?} is not finite") });
        }
        Ok(Self { kind: Kind::Primitive(primitive), offset })
    }

    /// A closed triangle mesh (in metres, its own frame) with its origin at `offset` in the tool
    /// frame.
    pub fn mesh(mesh: &incise_mesh::TriMesh, offset: Vec3) -> Result<Self, ShapeError> {
        if !offset.iter().all(|c| c.is_finite()) {
            return Err(ShapeError { what: format!("offset {offset:?} is not finite") });
        }
        Ok(Self { kind: Kind::Mesh(Arc::new(MeshShape::new(mesh))), offset })
    }

    /// A mesh shape's closed surface in the tool frame (its vertices with the offset applied,
    /// and its outward triangles): what volume contact rasterises. `None` for a primitive.
    #[must_use]
    pub fn closed_surface(&self) -> Option<(Vec<Vec3>, &[[u32; 3]])> {
        match &self.kind {
            Kind::Primitive(_) => None,
            Kind::Mesh(mesh) => {
                let o = self.offset;
                let vertices =
                    mesh.vertices().iter().map(|p| std::array::from_fn(|k| p[k] + o[k])).collect();
                Some((vertices, mesh.triangles()))
            }
        }
    }

    /// Where the shape's origin is in the tool frame (m).
    #[must_use]
    pub fn offset(&self) -> Vec3 {
        self.offset
    }

    /// The primitive (`None` for a mesh).
    #[must_use]
    pub fn primitive(&self) -> Option<Primitive> {
        match &self.kind {
            Kind::Primitive(p) => Some(*p),
            Kind::Mesh(_) => None,
        }
    }

    /// The signed distance (m, negative inside) of tool-frame point `q`, and the outward unit
    /// normal there (the distance's gradient; on the medial axis of a box, the nearest face's).
    #[must_use]
    pub fn distance(&self, q: Vec3) -> (f64, Vec3) {
        match self.local(q) {
            (p, Local::Ball(radius)) => ball(p, radius),
            (p, Local::Box(h)) => cuboid(p, h),
            (p, Local::Mesh(mesh)) => mesh.distance(p),
        }
    }

    /// The signed distance alone (m, negative inside) of tool-frame point `q`: the same value as
    /// [`Shape::distance`]'s, without the normal.
    #[must_use]
    pub fn signed_distance(&self, q: Vec3) -> f64 {
        match self.local(q) {
            (p, Local::Ball(radius)) => ball(p, radius).0,
            (p, Local::Box(h)) => cuboid_distance(p, h),
            (p, Local::Mesh(mesh)) => mesh.distance(p).0,
        }
    }

    /// Tool-frame point `q` where the shape's distance is taken, and what it is taken to there.
    fn local(&self, q: Vec3) -> (Vec3, Local<'_>) {
        let p: Vec3 = std::array::from_fn(|k| q[k] - self.offset[k]);
        let primitive = match &self.kind {
            Kind::Primitive(primitive) => *primitive,
            Kind::Mesh(mesh) => return (p, Local::Mesh(mesh)),
        };
        match primitive {
            Primitive::Sphere { radius } => (p, Local::Ball(radius)),
            // A capsule is the ball about the nearest point of its axis.
            Primitive::Capsule { radius, length } => {
                ([p[0], p[1], p[2] - p[2].clamp(0.0, length)], Local::Ball(radius))
            }
            Primitive::Cuboid { half_extents } => (p, Local::Box(half_extents)),
            Primitive::Blade { length, height, thickness } => (
                [p[0], p[1], p[2] - 0.5 * height],
                Local::Box([0.5 * length, 0.5 * thickness, 0.5 * height]),
            ),
        }
    }

    /// The shape's bounding box in the tool frame, `(min, max)`.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let primitive = match &self.kind {
            Kind::Primitive(primitive) => *primitive,
            Kind::Mesh(mesh) => {
                let (lo, hi) = mesh.bounds();
                return (
                    std::array::from_fn(|k| lo[k] + self.offset[k]),
                    std::array::from_fn(|k| hi[k] + self.offset[k]),
                );
            }
        };
        let (lo, hi) = match primitive {
            Primitive::Sphere { radius } => ([-radius; 3], [radius; 3]),
            Primitive::Capsule { radius, length } => {
                ([-radius, -radius, -radius], [radius, radius, length + radius])
            }
            Primitive::Cuboid { half_extents } => (half_extents.map(|h| -h), half_extents),
            Primitive::Blade { length, height, thickness } => {
                ([-0.5 * length, -0.5 * thickness, 0.0], [0.5 * length, 0.5 * thickness, height])
            }
        };
        (
            std::array::from_fn(|k| lo[k] + self.offset[k]),
            std::array::from_fn(|k| hi[k] + self.offset[k]),
        )
    }

    /// The bounding box of the shape at `pose`, in the grid frame: the box of its tool-frame
    /// box's corners.
    #[must_use]
    pub fn grid_bounds(&self, pose: &crate::Pose) -> (Vec3, Vec3) {
        let (lo, hi) = self.bounds();
        let mut a = [f64::INFINITY; 3];
        let mut b = [f64::NEG_INFINITY; 3];
        for corner in 0..8 {
            let q = std::array::from_fn(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
            let p = pose.grid_from_tool(q);
            for k in 0..3 {
                a[k] = a[k].min(p[k]);
                b[k] = b[k].max(p[k]);
            }
        }
        (a, b)
    }

    /// The shape grown by `margin` (m) on every side: a primitive with each size grown (a box's
    /// corners stay sharp, a little more than the points within `margin` of the shape); a mesh
    /// is returned as it is.
    #[must_use]
    pub fn inflated(&self, margin: f64) -> Self {
        let Kind::Primitive(primitive) = &self.kind else { return self.clone() };
        let (primitive, offset) = match *primitive {
            Primitive::Sphere { radius } => {
                (Primitive::Sphere { radius: radius + margin }, self.offset)
            }
            Primitive::Capsule { radius, length } => {
                (Primitive::Capsule { radius: radius + margin, length }, self.offset)
            }
            Primitive::Cuboid { half_extents } => {
                (Primitive::Cuboid { half_extents: half_extents.map(|h| h + margin) }, self.offset)
            }
            Primitive::Blade { length, height, thickness } => (
                Primitive::Blade {
                    length: length + 2.0 * margin,
                    height: height + 2.0 * margin,
                    thickness: thickness + 2.0 * margin,
                },
                [self.offset[0], self.offset[1], self.offset[2] - margin],
            ),
        };
        Self { kind: Kind::Primitive(primitive), offset }
    }

    /// The shape's thinnest dimension (m): a moving tool is tested for crossing points at
    /// sub-steps shorter than half of it, so that nothing passes through it between two tests.
    /// For a mesh, the smallest extent of its bounding box (an upper bound for a mesh with
    /// thinner parts inside its box; such a tool moving fast is sampled more coarsely than its
    /// thinnest part).
    #[must_use]
    pub fn thinnest(&self) -> f64 {
        let primitive = match &self.kind {
            Kind::Primitive(primitive) => *primitive,
            Kind::Mesh(mesh) => {
                let (lo, hi) = mesh.bounds();
                return (0..3).map(|k| hi[k] - lo[k]).fold(f64::INFINITY, f64::min);
            }
        };
        match primitive {
            Primitive::Sphere { radius } | Primitive::Capsule { radius, .. } => 2.0 * radius,
            Primitive::Cuboid { half_extents } => {
                2.0 * half_extents.iter().copied().fold(f64::INFINITY, f64::min)
            }
            Primitive::Blade { length, height, thickness } => length.min(height).min(thickness),
        }
    }

    /// Whether the ray from `q` along the unit direction `d` (tool frame) meets the shape before
    /// it is past the shape's bounding box: sphere tracing, each step the distance to the shape,
    /// which never oversteps its surface.
    #[must_use]
    pub fn ray_meets(&self, q: Vec3, d: Vec3) -> bool {
        let (lo, hi) = self.bounds();
        let reach = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
            + (0..3).map(|k| (q[k] - 0.5 * (lo[k] + hi[k])).powi(2)).sum::<f64>().sqrt();
        let tiny = 1e-9 * reach.max(1e-12);
        let mut s = 0.0;
        // Each step is at least the distance to the surface, so a grazing ray near a face takes
        // many; past this many it is taken as missing.
        for _ in 0..256 {
            let phi = self.distance(std::array::from_fn(|k| q[k] + s * d[k])).0;
            if phi <= tiny {
                return true;
            }
            s += phi;
            if s > reach {
                return false;
            }
        }
        false
    }
}

/// What a shape's distance is taken to, about the origin of [`Shape::local`]'s point.
enum Local<'a> {
    /// A ball of this radius.
    Ball(f64),
    /// A box of these half extents.
    Box(Vec3),
    /// A closed mesh.
    Mesh(&'a MeshShape),
}

/// The signed distance and normal of a ball of `radius` about the origin.
fn ball(p: Vec3, radius: f64) -> (f64, Vec3) {
    let r = p.iter().map(|c| c * c).sum::<f64>().sqrt();
    // At the centre every direction is out; +z is as good as any and keeps results defined.
    let n = if r > 0.0 { p.map(|c| c / r) } else { [0.0, 0.0, 1.0] };
    (r - radius, n)
}

/// The signed distance of a box of half extents `h` about the origin ([`cuboid`]'s value).
fn cuboid_distance(p: Vec3, h: Vec3) -> f64 {
    let q: Vec3 = std::array::from_fn(|k| p[k].abs() - h[k]);
    let out_len = q.iter().map(|c| c.max(0.0) * c.max(0.0)).sum::<f64>().sqrt();
    if out_len > 0.0 {
        return out_len;
    }
    let axis = (0..3).fold(0, |best, k| if q[k] > q[best] { k } else { best });
    q[axis]
}

/// The signed distance and normal of a box of half extents `h` about the origin.
fn cuboid(p: Vec3, h: Vec3) -> (f64, Vec3) {
    let q: Vec3 = std::array::from_fn(|k| p[k].abs() - h[k]);
    let outside: Vec3 = q.map(|c| c.max(0.0));
    let out_len = outside.iter().map(|c| c * c).sum::<f64>().sqrt();
    if out_len > 0.0 {
        let n = std::array::from_fn(|k| outside[k].copysign(p[k]) / out_len);
        return (out_len, n);
    }
    // Inside: the nearest face, the first of equals so the result is deterministic.
    let axis = (0..3).fold(0, |best, k| if q[k] > q[best] { k } else { best });
    let mut n = [0.0; 3];
    n[axis] = if p[axis] < 0.0 { -1.0 } else { 1.0 };
    (q[axis], n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shapes() -> Vec<Shape> {
        vec![
            Shape::new(Primitive::Sphere { radius: 0.01 }, [0.0; 3]).unwrap(),
            Shape::new(Primitive::Capsule { radius: 0.003, length: 0.05 }, [0.001, 0.0, 0.0])
                .unwrap(),
            Shape::new(Primitive::Cuboid { half_extents: [0.01, 0.02, 0.005] }, [0.0; 3]).unwrap(),
            Shape::new(
                Primitive::Blade { length: 0.02, height: 0.01, thickness: 0.0005 },
                [0.0; 3],
            )
            .unwrap(),
        ]
    }

    #[test]
    fn the_distance_alone_is_the_distance_bit_for_bit() {
        for shape in shapes() {
            for i in 0..2000 {
                let q: Vec3 =
                    std::array::from_fn(|k| 0.03 * ((i * 7 + k * 13) as f64 * 0.37).sin());
                let (d, _) = shape.distance(q);
                assert_eq!(shape.signed_distance(q).to_bits(), d.to_bits(), "{shape:?} at {q:?}");
            }
        }
    }

    #[test]
    fn normals_are_the_distance_gradient() {
        // Central differences of a distance that is smooth away from the medial axis; 1e-6 is the
        // step's truncation error (h² · curvature ≈ 1e-14 / 1e-3) with rounding to spare.
        let h = 1e-8;
        for shape in shapes() {
            for i in 0..200 {
                let q: Vec3 =
                    std::array::from_fn(|k| 0.03 * ((i * 7 + k * 13) as f64 * 0.37).sin());
                let (_, n) = shape.distance(q);
                let g: Vec3 = std::array::from_fn(|k| {
                    let mut a = q;
                    let mut b = q;
                    a[k] += h;
                    b[k] -= h;
                    (shape.distance(a).0 - shape.distance(b).0) / (2.0 * h)
                });
                let diff = (0..3).map(|k| (g[k] - n[k]).abs()).fold(0.0, f64::max);
                let off_axis = (0..3).map(|k| g[k] * g[k]).sum::<f64>() > 0.999;
                if off_axis {
                    assert!(diff < 1e-5, "{shape:?} at {q:?}: gradient {g:?}, normal {n:?}");
                }
            }
        }
    }

    #[test]
    fn bounds_contain_the_shape_and_rays_toward_it_meet_it() {
        for shape in shapes() {
            let (lo, hi) = shape.bounds();
            for i in 0..500 {
                let q: Vec3 =
                    std::array::from_fn(|k| 0.06 * ((i * 11 + k * 5) as f64 * 0.91).sin());
                let inside = shape.distance(q).0 < 0.0;
                let within = (0..3).all(|k| lo[k] <= q[k] && q[k] <= hi[k]);
                assert!(!inside || within, "{shape:?}: {q:?} inside but outside its bounds");
            }
            let centre: Vec3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
            let below: Vec3 = std::array::from_fn(|k| centre[k] - if k == 0 { 0.2 } else { 0.0 });
            assert!(shape.ray_meets(below, [1.0, 0.0, 0.0]), "{shape:?}: toward it");
            assert!(!shape.ray_meets(below, [-1.0, 0.0, 0.0]), "{shape:?}: away from it");
            let beside: Vec3 = std::array::from_fn(|k| below[k] + if k == 1 { 0.2 } else { 0.0 });
            assert!(!shape.ray_meets(beside, [1.0, 0.0, 0.0]), "{shape:?}: beside it");
        }
    }

    #[test]
    fn an_inflated_shape_holds_what_lies_within_the_margin() {
        for shape in shapes() {
            let grown = shape.inflated(0.001);
            for i in 0..500 {
                let q: Vec3 = std::array::from_fn(|k| 0.06 * ((i * 7 + k * 3) as f64 * 0.53).sin());
                let d = shape.distance(q).0;
                if d < 0.001 - 1e-12 {
                    assert!(grown.distance(q).0 < 1e-12, "{shape:?}: {q:?} at {d} m");
                }
                if d > 0.001 * 3f64.sqrt() + 1e-12 {
                    assert!(grown.distance(q).0 > 0.0, "{shape:?}: {q:?} at {d} m");
                }
            }
        }
    }

    #[test]
    fn bad_sizes_are_refused() {
        let e = Shape::new(Primitive::Sphere { radius: -1.0 }, [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("radius is -1"), "{e}");
        assert!(
            Shape::new(Primitive::Capsule { radius: 1.0, length: f64::NAN }, [0.0; 3]).is_err()
        );
    }
}
