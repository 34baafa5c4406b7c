//! The benchmark's cut: a blade-shaped stroke of fine voxels through the organ.
//!
//! A blade one voxel thick is pressed down from the top of the organ in the plane through its
//! centroid (normal along x): the stroke holds the plane's material voxels ordered from the top
//! (largest z) down, so it is a full-width band whose depth grows with the voxel count. If the
//! plane has too few voxels the next planes are used.

use incise_grid::BranchedGrid;

/// The first `count` voxels of a blade stroke through `grid`'s organ (fewer if the organ is smaller).
pub fn blade_stroke(grid: &BranchedGrid, count: usize) -> Vec<u32> {
    let fine = grid.fine();
    let d = fine.dims();
    let n = d[0] * d[1] * d[2];
    let mut sum_x = 0.0;
    let mut voxels = 0usize;
    for v in 0..n {
        if fine.material(v).is_some() {
            sum_x += f64::from(v % d[0]);
            voxels += 1;
        }
    }
    let centre = if voxels == 0 { 0 } else { (sum_x / voxels as f64).round() as u32 };
    let mut out = Vec::with_capacity(count);
    for offset in 0..d[0] {
        // Planes centre, centre+1, centre−1, centre+2, … until the stroke is long enough.
        let step = offset.div_ceil(2);
        let x = if offset % 2 == 1 { centre.checked_add(step) } else { centre.checked_sub(step) };
        let Some(x) = x.filter(|&x| x < d[0]) else { continue };
        let mut plane: Vec<(u32, u32, u32)> = Vec::new();
        for z in 0..d[2] {
            for y in 0..d[1] {
                let v = x + d[0] * (y + d[1] * z);
                if fine.material(v).is_some() {
                    plane.push((d[2] - 1 - z, y, v));
                }
            }
        }
        plane.sort_unstable();
        out.extend(plane.iter().map(|&(_, _, v)| v).take(count - out.len()));
        if out.len() == count {
            break;
        }
    }
    out
}

/// The links a separation-mode blade severs along the same stroke: each stroke voxel's link to its
/// `+x` neighbour (the blade's plane lies between them, so no volume is lost).
pub fn blade_links(grid: &BranchedGrid, stroke: &[u32]) -> Vec<(u32, u32)> {
    let d = grid.fine().dims();
    stroke.iter().filter(|&&v| v % d[0] + 1 < d[0]).map(|&v| (v, v + 1)).collect()
}
