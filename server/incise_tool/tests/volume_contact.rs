//! Volume contact from layered depth images (Faure et al. 2008, paper 1 §3): the intersection
//! volume of closed surfaces against analytic volumes, its gradient against finite differences,
//! one surface overlapping itself, separation from a deep overlap, and the rasteriser's tie rule (a closed surface is crossed an even number of times on every
//! ray, even with vertices on pixel centres).

use incise_math::Vec3;
use incise_math::mat3::{axis_angle, cross, dot, mul_vec};
use incise_tool::volume_contact::{
    Fragment, Ldi, OverlapInterval, Side, TriangleSurface, View, intersection, intersection_in,
    overlaps, self_intersection, self_overlaps, self_overlaps_in,
};

/// A closed triangle surface owning its data.
struct Mesh {
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

impl Mesh {
    fn surface(&self) -> TriangleSurface<'_> {
        TriangleSurface { positions: &self.positions, triangles: &self.triangles }
    }

    /// Orients every triangle outwards from `centre` (the meshes here are star-shaped about it).
    fn orient_from(&mut self, centre: Vec3) {
        for t in &mut self.triangles {
            let p = t.map(|i| self.positions[i as usize]);
            let n = cross(&sub(p[1], p[0]), &sub(p[2], p[0]));
            let mid: Vec3 = std::array::from_fn(|a| (p[0][a] + p[1][a] + p[2][a]) / 3.0);
            if dot(&n, &sub(mid, centre)) < 0.0 {
                t.swap(1, 2);
            }
        }
    }

    /// The enclosed volume (divergence theorem).
    fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let p = t.map(|i| self.positions[i as usize]);
                dot(&p[0], &cross(&p[1], &p[2])) / 6.0
            })
            .sum()
    }
}

fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The box `lo..hi`, turned by `angle` about `axis` through its centre.
fn cuboid(lo: Vec3, hi: Vec3, axis: Vec3, angle: f64) -> Mesh {
    let centre: Vec3 = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let r = axis_angle(&axis, angle);
    let positions = (0..8)
        .map(|i| {
            let p: Vec3 = std::array::from_fn(|a| if i >> a & 1 == 1 { hi[a] } else { lo[a] });
            let q = mul_vec(&r, &sub(p, centre));
            std::array::from_fn(|a| q[a] + centre[a])
        })
        .collect();
    // Two triangles per face: the face's corners in cyclic order.
    let faces =
        [[0, 2, 6, 4], [1, 3, 7, 5], [0, 1, 5, 4], [2, 3, 7, 6], [0, 1, 3, 2], [4, 5, 7, 6]];
    let triangles = faces.iter().flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]]).collect();
    let mut m = Mesh { positions, triangles };
    m.orient_from(centre);
    m
}

/// An icosphere of radius `r` about `centre`, subdivided `levels` times (outward normals).
fn icosphere(centre: Vec3, r: f64, levels: usize) -> Mesh {
    let m = incise_mesh::generate::icosphere(centre, r, levels);
    Mesh { positions: m.vertices().to_vec(), triangles: m.triangles().to_vec() }
}

fn normalised(p: Vec3) -> Vec3 {
    let n = dot(&p, &p).sqrt();
    p.map(|x| x / n)
}

/// Volume of the lens where two balls of radius `r` with centres `d` apart overlap.
fn lens(r: f64, d: f64) -> f64 {
    if d >= 2.0 * r {
        return 0.0;
    }
    std::f64::consts::PI * (4.0 * r + d) * (2.0 * r - d).powi(2) / 12.0
}

#[test]
fn the_overlap_of_two_axis_aligned_boxes_is_exact() {
    // Every pixel centre lies inside the overlap's projection, so no view has a partly covered
    // pixel: each axis sees the overlap exactly, whatever the resolution.
    let a = cuboid([0.0; 3], [1.0; 3], [0.0, 0.0, 1.0], 0.0);
    let b = cuboid([0.5, 0.25, -0.3], [1.5, 1.25, 0.6], [0.0, 0.0, 1.0], 0.0);
    assert!((a.volume() - 1.0).abs() < 1e-12, "outward triangles");
    let want = 0.5 * 0.75 * 0.6;
    for resolution in [1, 7, 32] {
        let i = intersection(&a.surface(), &b.surface(), resolution);
        for (axis, v) in i.volume_by_axis.iter().enumerate() {
            assert!((v - want).abs() < 1e-12 * want, "axis {axis} at {resolution}: {v} ≠ {want}");
        }
        // Moving the faces that bound the overlap moves it by their area: B's face at x = 0.5
        // (area 0.75 × 0.6) shrinks it, A's face at x = 1 grows it.
        let face_x = |m: &Mesh, g: &[Vec3], x: f64| -> f64 {
            m.positions
                .iter()
                .zip(g)
                .filter(|(p, _)| (p[0] - x).abs() < 1e-12)
                .map(|(_, g)| g[0])
                .sum()
        };
        let (gb, ga) = (face_x(&b, &i.gradient_b, 0.5), face_x(&a, &i.gradient_a, 1.0));
        assert!((gb + 0.45).abs() < 1e-12, "∂V/∂x of B's face at 0.5: {gb}");
        assert!((ga - 0.45).abs() < 1e-12, "∂V/∂x of A's face at 1: {ga}");
    }
}

#[test]
#[expect(clippy::float_cmp, reason = "nothing is rasterised or summed: exactly zero")]
fn apart_and_disjoint_surfaces_have_no_intersection() {
    let a = cuboid([0.0; 3], [1.0; 3], [0.0, 0.0, 1.0], 0.3);
    let b = cuboid([2.0; 3], [3.0; 3], [1.0, 0.0, 0.0], 0.7);
    let i = intersection(&a.surface(), &b.surface(), 16);
    assert_eq!(i.volume, 0.0);
    assert!(i.gradient_a.iter().chain(&i.gradient_b).all(|g| *g == [0.0; 3]));
    // Boxes whose bounding boxes overlap but which do not touch.
    let c = cuboid([1.05, 0.0, 0.0], [2.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0);
    let d = cuboid([0.0; 3], [1.0; 3], [0.0, 0.0, 1.0], 0.0);
    assert_eq!(intersection(&c.surface(), &d.surface(), 16).volume, 0.0);
}

#[test]
fn two_spheres_overlap_by_the_lens_volume() {
    // The icospheres' vertices lie on the sphere of radius r and their faces outside the sphere
    // of radius r_in (the faces' least distance from the centre), so the meshes' intersection
    // lies between the lenses of those two radii. Rasterising adds at most a pixel row around
    // each view's silhouette: relative to the lens's projected area, the perimeter times the
    // pixel size over the area, which for a disc of the grid's width is 4 / resolution.
    let (r, d) = (1.0, 1.2);
    let a = icosphere([0.0; 3], r, 4);
    let b = icosphere([d * 0.6, d * 0.64, d * 0.48], r, 4);
    let r_in = a
        .triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| a.positions[i as usize]);
            let n = normalised(cross(&sub(p[1], p[0]), &sub(p[2], p[0])));
            dot(&n, &p[0]).abs()
        })
        .fold(f64::INFINITY, f64::min);
    let (low, high) = (lens(r_in, d), lens(r, d));
    for resolution in [64, 128] {
        let slack = 4.0 / resolution as f64;
        let i = intersection(&a.surface(), &b.surface(), resolution);
        println!(
            "resolution {resolution}: volume {:.6} (x {:.6}, y {:.6}, z {:.6}); lens between {low:.6} (r_in {r_in:.5}) and {high:.6}",
            i.volume, i.volume_by_axis[0], i.volume_by_axis[1], i.volume_by_axis[2]
        );
        for v in i.volume_by_axis {
            assert!(
                v >= low * (1.0 - slack) && v <= high * (1.0 + slack),
                "{v} outside [{low}, {high}] ± {slack}"
            );
        }
    }
}

#[test]
fn the_gradient_is_the_derivative_of_the_rasterised_volume() {
    // On a fixed pixel grid each axis's volume is, near a configuration where no pixel centre
    // lies on an edge, a smooth function of the vertices: central differences of it must give
    // the gradient's component along that axis to rounding. Turned boxes and a sphere, so that
    // every crossing lies inside a tilted triangle.
    let a = cuboid([0.0; 3], [1.0; 3], [1.0, 2.0, 3.0], 0.4);
    let b = icosphere([0.9, 0.8, 0.7], 0.55, 2);
    let region = ([-0.5; 3], [1.6; 3]);
    let base = intersection_in(&a.surface(), &b.surface(), region, 24);
    assert!(base.volume > 0.05, "the shapes overlap: {}", base.volume);
    let h = 1e-6;
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for (which, mesh, gradient) in [(0, &a, &base.gradient_a), (1, &b, &base.gradient_b)] {
        for v in 0..mesh.positions.len().min(20) {
            for axis in 0..3 {
                let moved = |delta: f64| {
                    let mut positions = mesh.positions.clone();
                    positions[v][axis] += delta;
                    let m = TriangleSurface { positions: &positions, triangles: &mesh.triangles };
                    let i = if which == 0 {
                        intersection_in(&m, &b.surface(), region, 24)
                    } else {
                        intersection_in(&a.surface(), &m, region, 24)
                    };
                    i.volume_by_axis[axis]
                };
                let fd = (moved(h) - moved(-h)) / (2.0 * h);
                let g = gradient[v][axis];
                worst = worst.max((fd - g).abs());
                assert!(
                    (fd - g).abs() < 1e-6,
                    "surface {which} vertex {v} axis {axis}: {g} vs {fd}"
                );
                checked += usize::from(g != 0.0);
            }
        }
    }
    println!("{checked} non-zero components checked, largest difference {worst:e}");
    assert!(checked > 10, "the test moved vertices that bound the intersection");
}

#[test]
fn a_closed_surface_is_crossed_in_pairs_on_every_ray_even_through_its_vertices() {
    // A box whose corners and edges fall exactly on pixel centres and a sphere with a vertex on
    // the grid: every ray enters as often as it leaves, in alternation.
    let cube = cuboid([-1.0; 3], [1.0; 3], [0.0, 0.0, 1.0], 0.0);
    let sphere = icosphere([0.0; 3], 1.0, 3);
    for mesh in [&cube, &sphere] {
        for axis in 0..3 {
            for resolution in [2, 4, 9] {
                let view = View::covering(axis, [-1.5; 3], [1.5; 3], resolution);
                let ldi = Ldi::rasterize(&mesh.surface(), &view);
                for p in 0..ldi.pixel_count() {
                    let f = ldi.pixel(p);
                    assert!(
                        f.len().is_multiple_of(2),
                        "axis {axis}, pixel {p}: {} crossings",
                        f.len()
                    );
                    for (k, x) in f.iter().enumerate() {
                        assert_eq!(x.entering, k % 2 == 0, "axis {axis}, pixel {p}: {f:?}");
                    }
                }
            }
        }
    }
}

/// Both meshes as one surface (vertices of `b` after those of `a`).
fn joined(a: &Mesh, b: &Mesh) -> Mesh {
    let shift = a.positions.len() as u32;
    Mesh {
        positions: a.positions.iter().chain(&b.positions).copied().collect(),
        triangles: a
            .triangles
            .iter()
            .copied()
            .chain(b.triangles.iter().map(|t| t.map(|v| v + shift)))
            .collect(),
    }
}

#[test]
fn a_surface_overlapping_itself_has_the_volume_of_its_overlapping_parts() {
    // One surface made of two interpenetrating spheres (a cut flap pressed into its neighbour is
    // the same situation) is inside two layers exactly where the spheres intersect. Seen through
    // the same pixel grid, its self-overlap and gradient are the two spheres' intersection's.
    let a = icosphere([0.0; 3], 1.0, 3);
    let b = icosphere([0.7, 0.5, 0.3], 0.8, 3);
    let one = joined(&a, &b);
    let alone = self_intersection(&a.surface(), 48);
    assert!(alone.volume.abs() < 1e-15, "a sphere does not overlap itself: {}", alone.volume);
    let own = self_intersection(&one.surface(), 48);
    let region = one.surface().bounds().unwrap();
    let pair = intersection_in(&a.surface(), &b.surface(), region, 48);
    println!("self-overlap {:.6}, intersection {:.6}", own.volume, pair.volume);
    assert!(own.volume > 0.3);
    for k in 0..3 {
        let (x, y) = (own.volume_by_axis[k], pair.volume_by_axis[k]);
        assert!((x - y).abs() <= 1e-12 * y, "axis {k}: {x} against {y}");
    }
    let both: Vec<Vec3> = pair.gradient_a.iter().chain(&pair.gradient_b).copied().collect();
    for (v, (g, h)) in own.gradient.iter().zip(&both).enumerate() {
        for k in 0..3 {
            assert!((g[k] - h[k]).abs() <= 1e-12, "vertex {v} axis {k}: {g:?} against {h:?}");
        }
    }
}

#[test]
fn following_the_gradient_separates_even_a_deep_overlap() {
    // Two balls nearly on top of each other (centres 0.3 radius apart), no distance field: the
    // gradient's resultant on each body points away from the other, and moving them apart along
    // it shrinks the overlap at every step until it is gone.
    let a = icosphere([0.0; 3], 1.0, 3);
    let mut b = icosphere([0.3, 0.0, 0.0], 1.0, 3);
    let sum = |g: &[Vec3]| -> Vec3 {
        g.iter().fold([0.0; 3], |s, x| std::array::from_fn(|k| s[k] + x[k]))
    };
    let mut volume = f64::INFINITY;
    for step in 0..40 {
        let i = intersection(&a.surface(), &b.surface(), 48);
        if i.volume <= 0.0 {
            println!("apart after {step} steps");
            return;
        }
        assert!(i.volume < volume, "step {step}: the overlap grew from {volume} to {}", i.volume);
        volume = i.volume;
        // ∂V/∂(translation of b) is the sum of b's vertex gradients; a's is its opposite.
        let (ga, gb) = (sum(&i.gradient_a), sum(&i.gradient_b));
        let n = dot(&gb, &gb).sqrt();
        assert!(
            gb[0] < -0.95 * n,
            "step {step}: b is pushed along -∇ = {:?}, not away from a",
            gb.map(|x| -x)
        );
        assert!(
            (0..3).all(|k| (ga[k] + gb[k]).abs() < 0.05 * n),
            "step {step}: {ga:?} and {gb:?} not opposite"
        );
        // A step of 0.1 along the direction that shrinks the overlap.
        for p in &mut b.positions {
            for k in 0..3 {
                p[k] -= 0.1 * gb[k] / n;
            }
        }
    }
    panic!("still overlapping after 40 steps: {volume}");
}

#[test]
fn separate_overlaps_are_separate_regions_that_sum_to_the_whole() {
    // A long bar crossed by two boxes far apart: two overlaps, each pushed by its own volume.
    // Their volumes and gradients sum to the whole intersection's (same views), and each
    // equals the intersection of the bar with that box alone seen through the same pixels.
    let bar = cuboid([0.0, 0.0, 0.0], [10.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0);
    let left = cuboid([1.0, 0.5, 0.5], [2.0, 1.5, 1.5], [0.0, 0.0, 1.0], 0.0);
    let right = cuboid([7.5, -0.5, 0.25], [8.0, 0.5, 1.25], [0.0, 0.0, 1.0], 0.0);
    let boxes = joined(&left, &right);
    let resolution = 40;
    let regions = overlaps(&bar.surface(), &boxes.surface(), resolution);
    assert_eq!(regions.len(), 2, "two overlaps far apart");
    let whole = intersection(&bar.surface(), &boxes.surface(), resolution);
    let total: f64 = regions.iter().map(|r| r.volume).sum();
    assert!((total - whole.volume).abs() <= 1e-12 * whole.volume, "{total} ≠ {}", whole.volume);
    let mut summed = vec![[0.0; 3]; bar.positions.len()];
    for r in &regions {
        for &(v, g) in &r.gradient_a {
            for k in 0..3 {
                summed[v as usize][k] += g[k];
            }
        }
    }
    for (v, (g, h)) in summed.iter().zip(&whole.gradient_a).enumerate() {
        assert!((0..3).all(|k| (g[k] - h[k]).abs() <= 1e-12), "vertex {v}: {g:?} ≠ {h:?}");
    }
    // The regions are the bar against each box alone, seen through the same pixels (the views
    // over the overlap of the bar's and both boxes' bounding boxes), in whichever order the
    // views meet them first.
    let view_box = ([1.0, 0.0, 0.25], [8.0, 1.0, 1.0]);
    let mut alone: Vec<f64> = [&left, &right]
        .iter()
        .map(|other| intersection_in(&bar.surface(), &other.surface(), view_box, resolution).volume)
        .collect();
    let mut found: Vec<f64> = regions.iter().map(|r| r.volume).collect();
    alone.sort_by(f64::total_cmp);
    found.sort_by(f64::total_cmp);
    println!("regions {found:?}, each box alone {alone:?} (true overlaps 0.1875 and 0.25)");
    for (x, y) in found.iter().zip(&alone) {
        assert!((x - y).abs() <= 1e-12 * y, "{x} ≠ {y}");
    }
    // Self-overlaps: the bar and the boxes as one surface overlap itself in the same two
    // places; a region around the right box alone sees only that one.
    let all = joined(&bar, &boxes);
    let own = self_overlaps(&all.surface(), resolution);
    assert_eq!(own.len(), 2);
    let around = ([7.0, -1.0, 0.0], [8.5, 1.5, 1.5]);
    let near_right = self_overlaps_in(&all.surface(), around, 32);
    assert_eq!(near_right.len(), 1);
    let alone = intersection_in(&bar.surface(), &right.surface(), around, 32).volume;
    assert!((near_right[0].volume - alone).abs() <= 1e-12 * alone, "{}", near_right[0].volume);
    assert!(near_right[0].gradient_b.is_empty(), "a self-overlap has one side");
}

/// An end of a ray's interval: its depth, the surface, and the crossing that makes it (the
/// triangle's vertices and weights), `None` where the region's face cuts it.
type End = (f64, Side, Option<([u32; 3], [f64; 3])>);

/// One ray's intervals inside at least `layers` of `surface` (on `side`), cut to `near..far`
/// where given. Written from the definition, over every crossing of the ray.
fn inside_by_definition(
    surface: &TriangleSurface<'_>,
    side: Side,
    fragments: &[Fragment],
    layers: i32,
    clip: Option<(f64, f64)>,
) -> Vec<(End, End)> {
    let (near, far) = clip.unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
    let crossing = |f: &Fragment| Some((surface.triangles[f.triangle as usize], f.weights));
    let mut out = Vec::new();
    let mut winding = 0;
    let mut start: Option<&Fragment> = None;
    for f in fragments {
        let before = winding;
        winding += if f.entering { 1 } else { -1 };
        if before < layers && winding >= layers {
            start = Some(f);
        } else if before >= layers && winding < layers {
            let s = start.take().unwrap();
            let s = if s.depth < near { (near, side, None) } else { (s.depth, side, crossing(s)) };
            let e = if f.depth > far { (far, side, None) } else { (f.depth, side, crossing(f)) };
            if e.0 > s.0 {
                out.push((s, e));
            }
        }
    }
    assert_eq!(winding, 0, "a closed surface's ray leaves it as often as it enters");
    out
}

/// What `overlap_intervals` (with `b`, over a region holding the intersection) or
/// `self_overlap_intervals` (without; cut to the region) must give, from the definition: every
/// triangle rasterised in every view, each ray's intervals walked over all its crossings, every
/// pair of intervals of the two surfaces intersected.
#[expect(clippy::float_cmp, reason = "the tie rule is for exactly equal depths")]
fn intervals_by_definition(
    a: &TriangleSurface<'_>,
    b: Option<&TriangleSurface<'_>>,
    (lo, hi): (Vec3, Vec3),
    resolution: usize,
) -> Vec<OverlapInterval> {
    let mut out = Vec::new();
    for axis in 0..3 {
        let view = View::covering(axis, lo, hi, resolution);
        let la = Ldi::rasterize(a, &view);
        let lb = b.map(|b| (b, Ldi::rasterize(b, &view)));
        let depths = (lo[axis], hi[axis]);
        for p in 0..la.pixel_count() {
            let pixel = [p % view.size[0], p / view.size[0]];
            let mut push = |s: End, e: End| {
                let bound = |x: End| {
                    let (tri, w) = x.2.unwrap_or(([0; 3], [0.0; 3]));
                    (x.1, tri, w)
                };
                out.push(OverlapInterval {
                    axis,
                    pixel,
                    area: view.pixel_area(),
                    depths: [s.0, e.0],
                    bounds: [bound(s), bound(e)],
                });
            };
            let Some((b, lb)) = &lb else {
                for (s, e) in inside_by_definition(a, Side::A, la.pixel(p), 2, Some(depths)) {
                    push(s, e);
                }
                continue;
            };
            let ia = inside_by_definition(a, Side::A, la.pixel(p), 1, None);
            let ib = inside_by_definition(b, Side::B, lb.pixel(p), 1, None);
            // The later start and the earlier end bound an overlap: A's at equal depth, unless
            // A's is a cut and B's a crossing.
            let first = |x: &End, y: &End| x.2.is_some() || y.2.is_none();
            for &(sa, ea) in &ia {
                for &(sb, eb) in &ib {
                    let s = if sa.0 > sb.0 || (sa.0 == sb.0 && first(&sa, &sb)) { sa } else { sb };
                    let e = if ea.0 < eb.0 || (ea.0 == eb.0 && first(&ea, &eb)) { ea } else { eb };
                    if e.0 > s.0 {
                        push(s, e);
                    }
                }
            }
        }
    }
    out
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

    /// Against a still surface, over a box that stays put (its own, or a larger one), the
    /// images kept from one pass to the next give exactly the intervals of the definition:
    /// while the other surface moves, after the still one moves (its images drawn again), and
    /// after its triangles change with its vertices unmoved.
    #[test]
    fn a_still_surfaces_kept_images_change_no_interval(
        offset in proptest::array::uniform3(-0.9f64..0.9),
        step in proptest::array::uniform3(-0.3f64..0.3),
        half in 0.4f64..1.2,
        angle in 0.0f64..3.0,
        resolution in 1usize..24,
    ) {
        use incise_tool::volume_contact::Passes;
        type Checked = Result<(), proptest::test_runner::TestCaseError>;
        let still = cuboid([-half; 3], [half; 3], normalised([1.0, 2.0, 0.5]), angle);
        let mut passes = Passes::default();
        let mut check = |moving: &Mesh, still: &Mesh, region: Option<(Vec3, Vec3)>| -> Checked {
            let (sa, sb) = (moving.surface(), still.surface());
            // The still surface's own box holds the intersection, as does any larger one.
            let region = region.unwrap_or_else(|| sb.bounds().unwrap());
            let mut kept = Vec::new();
            passes.overlap_intervals_against_still(&sa, &sb, region, resolution, &mut kept);
            let defined = intervals_by_definition(&sa, Some(&sb), region, resolution);
            proptest::prop_assert_eq!(kept, defined);
            Ok(())
        };
        let mut moving = icosphere(offset, 1.0, 2);
        check(&moving, &still, None)?;
        for p in &mut moving.positions {
            for k in 0..3 {
                p[k] += step[k];
            }
        }
        check(&moving, &still, None)?;
        let mut moved = cuboid([-half; 3], [half; 3], normalised([1.0, 2.0, 0.5]), angle);
        moved.positions[0] = moved.positions[0].map(|x| 1.1 * x);
        check(&moving, &moved, None)?;
        // The same vertices, unmoved, but the triangles now use a shifted copy of them, over a
        // box that holds both.
        let large = Some(([-3.0; 3], [3.0; 3]));
        let mut renumbered =
            Mesh { positions: moved.positions.clone(), triangles: moved.triangles.clone() };
        renumbered.positions.extend(moved.positions.iter().map(|p| p.map(|x| x + 0.25)));
        check(&moving, &renumbered, large)?;
        renumbered.triangles = moved.triangles.iter().map(|t| t.map(|v| v + 8)).collect();
        check(&moving, &renumbered, large)?;
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]

    /// The passes rasterise only the triangles that can bound an interval inside the region
    /// (over the region's columns, not wholly beyond it, not beyond everything of the other
    /// surface), yet give exactly the intervals that the definition gives from every crossing
    /// of every ray: for a sphere and a turned box over their common box and over larger ones,
    /// and for the two joined into one surface against itself, over those and over a box that
    /// cuts through them.
    #[test]
    fn skipping_the_triangles_no_view_needs_changes_no_interval(
        offset in proptest::array::uniform3(-0.9f64..0.9),
        half in 0.4f64..1.2,
        angle in 0.0f64..3.0,
        grow in proptest::array::uniform3(0.0f64..0.5),
        corner in proptest::array::uniform3(-1.2f64..0.2),
        size in proptest::array::uniform3(0.2f64..2.0),
        resolution in 1usize..24,
    ) {
        use incise_tool::volume_contact::{overlap_intervals, self_overlap_intervals};
        let a = icosphere([0.0; 3], 1.0, 2);
        let b = cuboid(
            offset.map(|x| x - half),
            offset.map(|x| x + half),
            normalised([1.0, 2.0, 0.5]),
            angle,
        );
        let one = joined(&a, &b);
        let (sa, sb, so) = (a.surface(), b.surface(), one.surface());
        let ((alo, ahi), (blo, bhi)) = (sa.bounds().unwrap(), sb.bounds().unwrap());
        let common: (Vec3, Vec3) = (
            std::array::from_fn(|k| alo[k].max(blo[k])),
            std::array::from_fn(|k| ahi[k].min(bhi[k])),
        );
        let grown: (Vec3, Vec3) = (
            std::array::from_fn(|k| common.0[k] - grow[k]),
            std::array::from_fn(|k| common.1[k] + grow[(k + 1) % 3]),
        );
        let cut: (Vec3, Vec3) = (corner, std::array::from_fn(|k| corner[k] + size[k]));
        for (region, holds_intersection) in [(common, true), (grown, true), (cut, false)] {
            if (0..3).any(|k| region.0[k] >= region.1[k]) {
                continue;
            }
            if holds_intersection {
                proptest::prop_assert_eq!(
                    overlap_intervals(&sa, &sb, region, resolution),
                    intervals_by_definition(&sa, Some(&sb), region, resolution)
                );
            }
            proptest::prop_assert_eq!(
                self_overlap_intervals(&so, region, resolution),
                intervals_by_definition(&so, None, region, resolution)
            );
        }
    }
}

#[test]
fn a_tool_meshs_force_and_its_derivative_follow_the_overlap() {
    // A tool box pressed flat into an organ box, its bottom 0.1 below the organ's top: the
    // overlap is 0.6 × 0.6 × 0.1. The tool's penalty force is `−k V Σ gᵢ` over its vertices:
    // straight up, `k V a` with `a` the face's area (0.36). The Jacobian's translation block
    // must match central differences of that force as the tool moves (V re-measured, the tool
    // moved by a whole pixel so that every view, not only z's, sees the move exactly; the
    // gradient of a flat face does not change as it moves along its normal, so to rounding),
    // and the two sides' gradients must cancel (moving both together changes nothing).
    use incise_tool::Linearisation;
    let organ = cuboid([0.0; 3], [1.0; 3], [0.0, 0.0, 1.0], 0.0);
    let tool_at =
        |dz: f64| cuboid([0.2, 0.2, 0.9 + dz], [0.8, 0.8, 1.5 + dz], [0.0, 0.0, 1.0], 0.0);
    // Pixels of 0.05 whose edges fall on the boxes' faces: the views measure the boxes exactly.
    let region = ([-0.2; 3], [1.4; 3]);
    let origin = [0.5, 0.5, 0.9];
    let k = 1e3;
    let force = |dz: f64| {
        let tool = tool_at(dz);
        let i = intersection_in(&organ.surface(), &tool.surface(), region, 32);
        let gradients = tool.positions.iter().copied().zip(i.gradient_b.iter().copied());
        let moved: Vec3 = [origin[0], origin[1], origin[2] + dz];
        (Linearisation::of_overlap(moved, k, i.volume, gradients), i)
    };
    let (lin, i) = force(0.0);
    assert!((i.volume - 0.036).abs() < 1e-9, "the overlap: {}", i.volume);
    let sum = |g: &[Vec3]| -> Vec3 { std::array::from_fn(|a| g.iter().map(|v| v[a]).sum()) };
    let (ga, gb) = (sum(&i.gradient_a), sum(&i.gradient_b));
    for a in 0..3 {
        assert!((ga[a] + gb[a]).abs() < 1e-9, "the sides' gradients cancel: {ga:?} {gb:?}");
    }
    let up = k * 0.036 * 0.36;
    println!("force {:?}, torque {:?}, expected up {up}", lin.force, lin.torque);
    assert!((lin.force[2] - up).abs() < 1e-9 * up && lin.force[0].abs() < 1e-12);
    assert!(lin.torque.iter().all(|t| t.abs() < 1e-9 * up), "about its centre: {:?}", lin.torque);
    let h = 0.05;
    let fd = (force(h).0.force[2] - force(-h).0.force[2]) / (2.0 * h);
    println!("∂F_z/∂z: {} against central differences {fd}", lin.jacobian[2][2]);
    assert!((lin.jacobian[2][2] - fd).abs() < 1e-6 * fd.abs(), "{} vs {fd}", lin.jacobian[2][2]);
    assert!((lin.jacobian[2][2] + k * 0.36 * 0.36).abs() < 1e-9, "−k a²");
    // Symmetric and non-positive: extrapolating with it adds no energy.
    for r in 0..6 {
        for c in 0..6 {
            assert!((lin.jacobian[r][c] - lin.jacobian[c][r]).abs() <= 1e-12 * up);
        }
        assert!(lin.jacobian[r][r] <= 0.0);
    }
    // Apart: nothing.
    let none = Linearisation::of_overlap(origin, k, -1e-3, [([0.0; 3], [0.0, 0.0, 1.0])]);
    assert_eq!(none, Linearisation::none(origin));
}
