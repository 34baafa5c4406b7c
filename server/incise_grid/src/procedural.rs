//! Procedural label volumes, so tests, benchmarks and the default scene need no files: a sphere,
//! an ellipsoid with a stiffer inclusion, a U-tube whose arms share coarse cells, a thin slab and
//! two touching blobs. Each is a plain [`LabelVolume`] with labels [`TISSUE`] (and [`TUMOUR`]).

use crate::volume::LabelVolume;
use incise_math::Vec3;

/// Label of the bulk tissue in every procedural volume.
pub const TISSUE: u16 = 1;
/// Label of the stiffer inclusion in [`ellipsoid_with_inclusion`].
pub const TUMOUR: u16 = 2;

/// A volume of `dims` voxels of edge `spacing` (m) whose label is `f(x, y, z)` at voxel centres
/// given in voxel units.
///
/// # Panics
/// If `dims` has a zero or `spacing` is not positive (procedural volumes are built from constants).
#[must_use]
pub fn from_fn(dims: [usize; 3], spacing: Vec3, f: impl Fn(f64, f64, f64) -> u16) -> LabelVolume {
    let mut labels = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                labels.push(f(x as f64, y as f64, z as f64));
            }
        }
    }
    LabelVolume::new(dims, spacing, labels).expect("procedural volume parameters are valid")
}

/// A ball of tissue filling an `n³` box (radius `n/2 − 0.5` voxels).
#[must_use]
pub fn sphere(n: usize, spacing: f64) -> LabelVolume {
    let c = (n as f64 - 1.0) / 2.0;
    let r2 = (n as f64 / 2.0 - 0.5).powi(2);
    from_fn([n; 3], [spacing; 3], |x, y, z| {
        u16::from((x - c).powi(2) + (y - c).powi(2) + (z - c).powi(2) <= r2) * TISSUE
    })
}

/// An ellipsoid of tissue with semi-axes `(0.48, 0.36, 0.3)·n` voxels, holding an off-centre
/// spherical inclusion labelled [`TUMOUR`] of radius `0.12·n`.
#[must_use]
pub fn ellipsoid_with_inclusion(n: usize, spacing: f64) -> LabelVolume {
    let nf = n as f64;
    let dims = [n, (0.75 * nf).ceil() as usize, (0.625 * nf).ceil() as usize];
    let c = dims.map(|d| (d as f64 - 1.0) / 2.0);
    let axes = [0.48 * nf, 0.36 * nf, 0.3 * nf];
    let tumour = [c[0] + 0.15 * nf, c[1], c[2] + 0.05 * nf];
    from_fn(dims, [spacing; 3], |x, y, z| {
        let p = [x, y, z];
        if (0..3).map(|a| (p[a] - tumour[a]).powi(2)).sum::<f64>() <= (0.12 * nf).powi(2) {
            TUMOUR
        } else if (0..3).map(|a| ((p[a] - c[a]) / axes[a]).powi(2)).sum::<f64>() <= 1.0 {
            TISSUE
        } else {
            0
        }
    })
}

/// An organ with a tumour in a box of `dims` voxels: the ellipsoid inscribed in the box
/// (semi-axes 0.48 of each edge) of [`TISSUE`], holding a sphere of [`TUMOUR`] (radius 0.3 of
/// the shortest semi-axis) set off the centre by a quarter of the x semi-axis and a tenth of the z
/// one, so that a tool pressed on the top near the centre meets it under a few millimetres of
/// tissue. The server's embedded scene and `procedural = "organ"` use it.
#[must_use]
pub fn organ(dims: [usize; 3], spacing: Vec3) -> LabelVolume {
    let c = dims.map(|d| (d as f64 - 1.0) / 2.0);
    let axes = dims.map(|d| 0.48 * d as f64);
    let radius = 0.3 * axes.iter().copied().fold(f64::INFINITY, f64::min);
    let tumour = [c[0] + 0.25 * axes[0], c[1], c[2] + 0.1 * axes[2]];
    from_fn(dims, spacing, |x, y, z| {
        let p = [x, y, z];
        if (0..3).map(|a| (p[a] - tumour[a]).powi(2)).sum::<f64>() <= radius * radius {
            TUMOUR
        } else if (0..3).map(|a| ((p[a] - c[a]) / axes[a]).powi(2)).sum::<f64>() <= 1.0 {
            TISSUE
        } else {
            0
        }
    })
}

/// Shape of [`u_tube`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UTube {
    /// Width (x) of each arm, in voxels.
    pub arm_width: usize,
    /// Gap (x) between the arms, in voxels.
    pub gap: usize,
    /// Height (z) of the base that joins the arms, in voxels.
    pub base_height: usize,
    /// Total height (z), in voxels.
    pub height: usize,
    /// Depth (y), in voxels.
    pub depth: usize,
}

impl UTube {
    /// Arms 5 voxels wide with a 2-voxel gap at x = 5, 6: no level-1 cell holds both arms, every
    /// level-2 cell over x 4..8 does, so the branching shows from level 2 up.
    pub const DEFAULT: Self = Self { arm_width: 5, gap: 2, base_height: 4, height: 16, depth: 4 };

    /// Which arm voxel column `x` belongs to: `Some(0)` left, `Some(1)` right, `None` the gap.
    #[must_use]
    pub fn arm_of(&self, x: usize) -> Option<usize> {
        if x < self.arm_width {
            Some(0)
        } else if x >= self.arm_width + self.gap && x < 2 * self.arm_width + self.gap {
            Some(1)
        } else {
            None
        }
    }
}

/// A U-shaped tube: two arms standing on a common base, separated by a gap narrower than a coarse
/// cell, so coarse cells hold material of both arms (the case of Jeřábková 2010, Fig. 3).
#[must_use]
pub fn u_tube(shape: UTube, spacing: f64) -> LabelVolume {
    let dims = [2 * shape.arm_width + shape.gap, shape.depth, shape.height];
    from_fn(dims, [spacing; 3], |x, _, z| {
        let solid = (z as usize) < shape.base_height || shape.arm_of(x as usize).is_some();
        u16::from(solid) * TISSUE
    })
}

/// A slab `thickness` voxels thick (z) and `n × n` wide: thin structures stress the branching.
#[must_use]
pub fn slab(n: usize, thickness: usize, spacing: f64) -> LabelVolume {
    from_fn([n, n, thickness.max(1)], [spacing; 3], |_, _, _| TISSUE)
}

/// Two balls of radius `0.25·n` whose surfaces touch along a small patch in the middle of an
/// `n × n/2 × n/2` box.
#[must_use]
pub fn two_blobs(n: usize, spacing: f64) -> LabelVolume {
    let nf = n as f64;
    let dims = [n, n.div_ceil(2), n.div_ceil(2)];
    let cy = (dims[1] as f64 - 1.0) / 2.0;
    let cz = (dims[2] as f64 - 1.0) / 2.0;
    let r = 0.25 * nf;
    let (c1, c2) = (0.25 * nf - 0.5, 0.75 * nf - 0.5);
    from_fn(dims, [spacing; 3], |x, y, z| {
        let d1 = (x - c1).powi(2) + (y - cy).powi(2) + (z - cz).powi(2);
        let d2 = (x - c2).powi(2) + (y - cy).powi(2) + (z - cz).powi(2);
        u16::from(d1 <= r * r || d2 <= r * r) * TISSUE
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_have_material_where_expected() {
        assert!(sphere(12, 1e-3).foreground_count() > 500);
        let e = ellipsoid_with_inclusion(24, 1e-3);
        let h = e.histogram();
        assert!(h.iter().any(|&(l, c)| l == TUMOUR && c > 50), "{h:?}");
        let u = u_tube(UTube::DEFAULT, 1e-3);
        assert_eq!(u.dims(), [12, 4, 16]);
        assert_eq!(u.label(5, 0, 10), 0, "the gap is empty above the base");
        assert_eq!(u.label(5, 0, 1), TISSUE, "the base joins the arms");
        assert_eq!(slab(8, 1, 1e-3).foreground_count(), 64);
        let b = two_blobs(16, 1e-3);
        let mid = b.dims()[0] / 2;
        assert!(
            (0..b.dims()[1]).any(|y| (0..b.dims()[2])
                .any(|z| b.label(mid, y, z) != 0 && b.label(mid - 1, y, z) != 0)),
            "the blobs touch"
        );
    }
}
