//! What the surface encloses: the analytic volume of a box for this construction, the two closed
//! surfaces of a separation cut, one surface per label group, and smoothing inside the voxels.

mod common;

use common::{H, block, check_surface, cut, grid_of, matches_full, voxel};
use incise_grid::GridEdit;
use incise_grid::procedural::{from_fn, sphere};
use incise_math::Vec3;
use incise_surface::{Surface, SurfaceOptions};

/// Volume enclosed by the live triangles of `group` (all groups for `None`), by the divergence
/// theorem.
fn volume(s: &Surface, group: Option<u16>) -> f64 {
    s.live_triangles()
        .filter(|(_, t)| group.is_none_or(|g| t.group == g))
        .map(|(_, t)| {
            let [a, b, c] = t.v.map(|v| s.vertices()[v as usize].rest);
            let cross =
                [b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2], b[0] * c[1] - b[1] * c[0]];
            (a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2]) / 6.0
        })
        .sum()
}

/// The volume this construction encloses for a full box of `n` voxels of edge lengths `h`.
///
/// Vertices sit at the centres of the box's outer voxel faces, so the surface is the box with its
/// edges and corners cut off: each face keeps the square through its outer face centres, each of
/// the 12 edges loses a prism of right-triangle section `(h_b/2)(h_c/2)/2` over the length between
/// the end voxels' centres `(n_a − 1)·h_a`, and each of the 8 corners loses `5/6` of the corner
/// box `(h/2)³` (the box minus the tetrahedron cut by the corner triangle). Altogether
/// `V = h_x h_y h_z · (n_x n_y n_z − (n_x + n_y + n_z)/2 + 2/3)`; one voxel gives the octahedron
/// through its face centres, `h³/6`.
fn box_volume(n: [usize; 3], h: Vec3) -> f64 {
    let count = (n[0] * n[1] * n[2]) as f64;
    let sum = (n[0] + n[1] + n[2]) as f64;
    h[0] * h[1] * h[2] * (count - sum / 2.0 + 2.0 / 3.0)
}

#[test]
fn a_box_encloses_its_analytic_volume() {
    // (volume dims, box origin, box size, spacing): boxes filling the volume (closed by the
    // padded cubes at the border) and boxes inside an empty margin.
    type Case = ([usize; 3], [usize; 3], [usize; 3], Vec3);
    let cases: [Case; 5] = [
        ([1, 1, 1], [0; 3], [1, 1, 1], [H; 3]),
        ([6, 6, 6], [0; 3], [6, 6, 6], [H; 3]),
        ([7, 8, 9], [2, 1, 3], [3, 4, 5], [H; 3]),
        ([5, 4, 3], [0; 3], [5, 4, 3], [1e-3, 2e-3, 1.5e-3]),
        ([9, 9, 9], [1, 2, 3], [7, 6, 5], [0.5e-3, 0.7e-3, 1.1e-3]),
    ];
    for (dims, lo, n, h) in cases {
        let v = from_fn(dims, h, |x, y, z| {
            let p = [x as usize, y as usize, z as usize];
            u16::from((0..3).all(|a| p[a] >= lo[a] && p[a] < lo[a] + n[a]))
        });
        let grid = grid_of(&v, 1, 1);
        let s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
        check_surface(&s).unwrap();
        // Exact arithmetic would give the formula; what is left is the rounding of a sum of a
        // few hundred terms of the result's size (measured: below 1e-14).
        let (got, want) = (s.enclosed_volume(&s.rest_positions()), box_volume(n, h));
        assert!((got - want).abs() <= 1e-12 * want, "{n:?} at {h:?}: {got:e} against {want:e}");
    }
}

#[test]
fn severing_a_plane_separates_two_closed_surfaces_without_losing_volume() {
    let o = SurfaceOptions::default();
    let mut grid = grid_of(&block([8, 8, 8], None), 1, 1);
    let d = grid.fine().dims();
    let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
    let voxels = grid.fine().voxel_count();
    let mut sever_links = Vec::new();
    for z in 0..d[2] {
        for y in 0..d[1] {
            sever_links.push((voxel(d, 3, y, z), voxel(d, 4, y, z)));
        }
    }
    let changes = cut(&mut grid, &mut s, &GridEdit { remove_voxels: vec![], sever_links });
    assert_eq!(grid.fine().voxel_count(), voxels, "separation removes no voxel");
    assert!(changes.vertices_removed.is_empty(), "the outer surface stays");
    check_surface(&s).unwrap();
    matches_full(&s, &grid, &o).unwrap();
    assert_eq!(s.components(), 2);
    // Two boxes of 4 × 8 × 8 voxels: the cut faces are coincident, one per side.
    let half = box_volume([4, 8, 8], [H; 3]);
    let got = volume(&s, None);
    assert!((got - 2.0 * half).abs() <= 1e-12 * half, "{got:e} against {:e}", 2.0 * half);
}

#[test]
fn each_label_group_gets_its_own_closed_surface() {
    let v = block([6, 5, 4], Some(2));
    let grid = grid_of(&v, 2, 1);
    let whole = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
    check_surface(&whole).unwrap();
    assert_eq!((whole.group_count(), whole.components()), (1, 1), "no internal interface");
    let want = box_volume([6, 5, 4], [H; 3]);
    assert!((volume(&whole, None) - want).abs() <= 1e-12 * want);

    let tissues = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::per_material(2));
    check_surface(&tissues).unwrap();
    assert_eq!((tissues.group_count(), tissues.components()), (2, 2));
    for (g, n) in [(0, [2, 5, 4]), (1, [4, 5, 4])] {
        let want = box_volume(n, [H; 3]);
        let got = volume(&tissues, Some(g));
        assert!((got - want).abs() <= 1e-12 * want, "group {g}: {got:e} against {want:e}");
    }
    // At the interface x = 2h both sides have a vertex on every voxel face, at the same place.
    let on_plane = |g: u16| -> Vec<[u64; 3]> {
        let mut p: Vec<[u64; 3]> = tissues
            .vertices()
            .iter()
            .filter(|v| v.alive && v.group == g && (v.rest[0] - 2.0 * H).abs() < 1e-15)
            .map(|v| v.rest.map(f64::to_bits))
            .collect();
        p.sort_unstable();
        p
    };
    assert_eq!(on_plane(0).len(), 5 * 4);
    assert_eq!(on_plane(0), on_plane(1));

    // A group may hold several materials: both together are the whole organ again.
    let both = SurfaceOptions { groups: vec![vec![0, 1]] };
    let merged = Surface::extract(grid.fine(), grid.spacing(), &both);
    assert_eq!(merged.canonical_triangles(), whole.canonical_triangles());
}

#[test]
fn smoothing_stays_near_the_owner_voxels_and_rounds_the_sphere() {
    let grid = grid_of(&sphere(16, H), 1, 2);
    let s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
    let smooth = s.smoothed_rest(10, 0.5);
    let d = s.dims();
    for (v, p) in s.vertices().iter().zip(&smooth) {
        if !v.alive {
            continue;
        }
        let x = [v.voxel % d[0], (v.voxel / d[0]) % d[1], v.voxel / (d[0] * d[1])];
        for a in 0..3 {
            let lo = (f64::from(x[a]) - 0.5) * H;
            let hi = (f64::from(x[a]) + 1.5) * H;
            assert!(p[a] >= lo && p[a] <= hi, "vertex of voxel {} left its box", v.voxel);
        }
    }
    // The voxel steps flatten: the spread of the distance to the centre shrinks.
    let c = 8.0 * H;
    let spread = |pos: &[Vec3]| {
        let r: Vec<f64> = s
            .vertices()
            .iter()
            .zip(pos)
            .filter(|(v, _)| v.alive)
            .map(|(_, p)| (0..3).map(|a| (p[a] - c).powi(2)).sum::<f64>().sqrt())
            .collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        (r.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt()
    };
    let (before, after) = (spread(&s.rest_positions()), spread(&smooth));
    let (v0, v1) = (s.enclosed_volume(&s.rest_positions()), s.enclosed_volume(&smooth));
    println!("radius spread {before:e} -> {after:e} m, volume {v0:e} -> {v1:e} m³");
    // Measured: 10 λ|μ pairs at λ = 0.5 take the spread to 52 % (2.05e-4 → 1.07e-4 m); the
    // bound leaves room for a different but equally valid fan or neighbour order.
    assert!(after < 0.65 * before, "smoothing rounds the voxel steps: {before:e} -> {after:e}");
    // Taubin's λ|μ pair is meant not to shrink or grow the shape (measured: +0.5 %); the bound is
    // four times that.
    assert!((v1 - v0).abs() < 0.02 * v0, "volume {v0:e} -> {v1:e}");
}
