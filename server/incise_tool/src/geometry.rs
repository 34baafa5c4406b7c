//! Small geometric kernels shared by the shapes and the proxy: closest points on triangles and
//! segments (Ericson, *Real-Time Collision Detection*, §5.1).

use incise_math::Vec3;
use incise_math::mat3::{cross, dot};
pub(crate) use incise_math::mat3::{norm, sub};

/// `a / |a|`, or `a` itself when it is zero.
pub(crate) fn unit(a: Vec3) -> Vec3 {
    let n = norm(a);
    if n > 0.0 { a.map(|c| c / n) } else { a }
}

/// The point with barycentric coordinates `b` of triangle `t`.
pub(crate) fn at_bary(t: &[Vec3; 3], b: [f64; 3]) -> Vec3 {
    std::array::from_fn(|k| b[0] * t[0][k] + b[1] * t[1][k] + b[2] * t[2][k])
}

/// The unit normal of triangle `t` by its winding (counter-clockwise seen from where it points),
/// zero for a degenerate one.
pub(crate) fn triangle_normal(t: &[Vec3; 3]) -> Vec3 {
    unit(cross(&sub(t[1], t[0]), &sub(t[2], t[0])))
}

/// Where the closest point of a triangle lies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Feature {
    Face,
    Edge(usize),
    Vertex(usize),
}

/// The closest point of a triangle to a point: its barycentric coordinates and its feature
/// (edge `e` runs from corner `e` to corner `e + 1`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Closest {
    pub(crate) bary: [f64; 3],
    pub(crate) point: Vec3,
    pub(crate) feature: Feature,
}

impl Closest {
    /// The point and its feature.
    pub(crate) fn point_feature(self) -> (Vec3, Feature) {
        (self.point, self.feature)
    }
}

/// The closest point of triangle `t` to `p` (Ericson §5.1.5).
pub(crate) fn closest_on_triangle(p: Vec3, t: [Vec3; 3]) -> Closest {
    let [a, b, c] = t;
    let done = |bary: [f64; 3], feature| Closest { bary, point: at_bary(&t, bary), feature };
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(&ab, &ap), dot(&ac, &ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return Closest { bary: [1.0, 0.0, 0.0], point: a, feature: Feature::Vertex(0) };
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(&ab, &bp), dot(&ac, &bp));
    if d3 >= 0.0 && d4 <= d3 {
        return Closest { bary: [0.0, 1.0, 0.0], point: b, feature: Feature::Vertex(1) };
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return Closest {
            bary: [1.0 - v, v, 0.0],
            point: std::array::from_fn(|k| a[k] + v * ab[k]),
            feature: Feature::Edge(0),
        };
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(&ab, &cp), dot(&ac, &cp));
    if d6 >= 0.0 && d5 <= d6 {
        return Closest { bary: [0.0, 0.0, 1.0], point: c, feature: Feature::Vertex(2) };
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return Closest {
            bary: [1.0 - w, 0.0, w],
            point: std::array::from_fn(|k| a[k] + w * ac[k]),
            feature: Feature::Edge(2),
        };
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return Closest {
            bary: [0.0, 1.0 - w, w],
            point: std::array::from_fn(|k| b[k] + w * (c[k] - b[k])),
            feature: Feature::Edge(1),
        };
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    done([1.0 - v - w, v, w], Feature::Face)
}

/// The closest points of segments `p0 → p1` and `q0 → q1`: their parameters `(s, t)` in [0, 1]
/// (Ericson §5.1.9).
pub(crate) fn closest_segments(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> (f64, f64) {
    let (d1, d2, r) = (sub(p1, p0), sub(q1, q0), sub(p0, q0));
    let (a, e, f) = (dot(&d1, &d1), dot(&d2, &d2), dot(&d2, &r));
    let tiny = 1e-30;
    if a <= tiny && e <= tiny {
        return (0.0, 0.0);
    }
    if a <= tiny {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = dot(&d1, &r);
    if e <= tiny {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = dot(&d1, &d2);
    let denom = a * e - b * b;
    let mut s = if denom > tiny * a * e { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
    let mut t = (b * s + f) / e;
    if t < 0.0 {
        t = 0.0;
        s = (-c / a).clamp(0.0, 1.0);
    } else if t > 1.0 {
        t = 1.0;
        s = ((b - c) / a).clamp(0.0, 1.0);
    }
    (s, t)
}

/// Where segment `p0 → p1` crosses triangle `t`: the segment's parameter and the point's
/// barycentric coordinates, if it does.
pub(crate) fn segment_crosses_triangle(
    p0: Vec3,
    p1: Vec3,
    t: &[Vec3; 3],
) -> Option<(f64, [f64; 3])> {
    // Möller–Trumbore on the segment's direction.
    let d = sub(p1, p0);
    let (e1, e2) = (sub(t[1], t[0]), sub(t[2], t[0]));
    let h = cross(&d, &e2);
    let det = dot(&e1, &h);
    let scale = dot(&e1, &e1).max(dot(&e2, &e2)) * norm(d);
    if det.abs() <= 1e-14 * scale {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(p0, t[0]);
    let u = inv * dot(&s, &h);
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(&s, &e1);
    let v = inv * dot(&d, &q);
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let along = inv * dot(&e2, &q);
    (0.0..=1.0).contains(&along).then_some((along, [1.0 - u - v, u, v]))
}

/// The closest points of segment `p0 → p1` and triangle `t`: the segment's parameter, the
/// triangle point's barycentric coordinates, and their distance.
pub(crate) fn closest_segment_triangle(p0: Vec3, p1: Vec3, t: &[Vec3; 3]) -> (f64, [f64; 3], f64) {
    if let Some((s, bary)) = segment_crosses_triangle(p0, p1, t) {
        return (s, bary, 0.0);
    }
    let seg = |s: f64| -> Vec3 { std::array::from_fn(|k| p0[k] + s * (p1[k] - p0[k])) };
    let mut best = (0.0, [1.0, 0.0, 0.0], f64::INFINITY);
    for s in [0.0, 1.0] {
        let c = closest_on_triangle(seg(s), *t);
        let d = norm(sub(seg(s), c.point));
        if d < best.2 {
            best = (s, c.bary, d);
        }
    }
    for e in 0..3 {
        let (a, b) = (t[e], t[(e + 1) % 3]);
        let (s, u) = closest_segments(p0, p1, a, b);
        let q: Vec3 = std::array::from_fn(|k| a[k] + u * (b[k] - a[k]));
        let d = norm(sub(seg(s), q));
        if d < best.2 {
            let mut bary = [0.0; 3];
            bary[e] = 1.0 - u;
            bary[(e + 1) % 3] = u;
            best = (s, bary, d);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: [Vec3; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    #[test]
    fn the_closest_point_of_a_triangle_has_the_barycentric_coordinates_it_reports() {
        for p in [[0.2, 0.2, 1.0], [-1.0, -1.0, 0.0], [2.0, -0.5, 0.3], [0.6, 0.6, -0.2]] {
            let c = closest_on_triangle(p, T);
            assert!((c.bary.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(c.bary.iter().all(|&b| b >= -1e-12));
            let q = at_bary(&T, c.bary);
            assert!(norm(sub(q, c.point)) < 1e-12, "{p:?}");
        }
        let above = closest_on_triangle([0.2, 0.2, 1.0], T);
        assert!(norm(sub(above.point, [0.2, 0.2, 0.0])) < 1e-15);
        assert_eq!(closest_on_triangle([0.6, 0.6, 0.0], T).feature, Feature::Edge(1));
    }

    #[test]
    fn a_segment_through_a_triangle_is_at_distance_zero_and_one_beside_it_is_not() {
        let (s, bary, d) = closest_segment_triangle([0.25, 0.25, 1.0], [0.25, 0.25, -1.0], &T);
        assert!(d == 0.0 && (s - 0.5).abs() < 1e-12);
        assert!(norm(sub(at_bary(&T, bary), [0.25, 0.25, 0.0])) < 1e-12);
        // Parallel to the hypotenuse, 0.3 beyond it in the plane and 0.4 above it.
        let off = 0.3 / std::f64::consts::SQRT_2;
        let (p0, p1) = ([1.0 + off, off, 0.4], [off, 1.0 + off, 0.4]);
        let (_, bary, d) = closest_segment_triangle(p0, p1, &T);
        assert!((d - 0.5).abs() < 1e-12, "{d}");
        assert!(bary[0].abs() < 1e-12, "on the hypotenuse: {bary:?}");
    }
}
