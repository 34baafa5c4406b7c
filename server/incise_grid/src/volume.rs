//! Segmented label volumes: the fine level every organ model starts from.
//!
//! A [`LabelVolume`] is a dense box of integer tissue labels (0 = empty) with its voxel spacing in
//! metres and its placement in world space. Cropping to the foreground and per-axis striding turn a
//! full CT segmentation into the fine level of a Dynamic Branched Grid (Jeřábková 2010, §2).

use crate::error::VolumeError;
use incise_math::Vec3;

/// Largest supported extent per axis: voxel indices are packed into `u32` and Morton codes use
/// 21 bits per axis.
pub const MAX_DIM: usize = 1 << 20;

/// A dense volume of tissue labels, `x` fastest, then `y`, then `z`.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelVolume {
    dims: [usize; 3],
    spacing: Vec3,
    origin: Vec3,
    direction: [[f64; 3]; 3],
    labels: Vec<u16>,
}

impl LabelVolume {
    /// A volume with the given extent, spacing (metres) and labels (`x` fastest), at the origin
    /// with axis-aligned orientation.
    pub fn new(dims: [usize; 3], spacing: Vec3, labels: Vec<u16>) -> Result<Self, VolumeError> {
        for (axis, &d) in dims.iter().enumerate() {
            if d == 0 || d > MAX_DIM {
                return Err(VolumeError::BadDimension { axis, value: d });
            }
        }
        for (axis, &h) in spacing.iter().enumerate() {
            if !(h.is_finite() && h > 0.0) {
                return Err(VolumeError::BadSpacing { axis, value: h });
            }
        }
        let expected = dims[0] * dims[1] * dims[2];
        if labels.len() != expected {
            return Err(VolumeError::SizeMismatch { expected, found: labels.len() });
        }
        Ok(Self { dims, spacing, origin: [0.0; 3], direction: IDENTITY, labels })
    }

    /// The same volume placed at `origin` (metres, world position of voxel (0,0,0)'s centre) with
    /// the columns of `direction` giving the world directions of the voxel axes.
    pub fn with_placement(
        mut self,
        origin: Vec3,
        direction: [[f64; 3]; 3],
    ) -> Result<Self, VolumeError> {
        if origin.iter().chain(direction.iter().flatten()).any(|v| !v.is_finite()) {
            return Err(VolumeError::BadPlacement);
        }
        self.origin = origin;
        self.direction = direction;
        Ok(self)
    }

    /// Voxels per axis.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Voxel size in metres per axis.
    #[must_use]
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// World position (metres) of the centre of voxel (0, 0, 0).
    #[must_use]
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Rotation from voxel axes to world axes: column `i` is the world direction of voxel axis `i`.
    #[must_use]
    pub fn direction(&self) -> [[f64; 3]; 3] {
        self.direction
    }

    /// Labels, `x` fastest.
    #[must_use]
    pub fn labels(&self) -> &[u16] {
        &self.labels
    }

    /// Linear index of voxel `(x, y, z)`.
    #[inline]
    #[must_use]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// Label of voxel `(x, y, z)`.
    #[inline]
    #[must_use]
    pub fn label(&self, x: usize, y: usize, z: usize) -> u16 {
        self.labels[self.index(x, y, z)]
    }

    /// Number of voxels with a non-zero label.
    #[must_use]
    pub fn foreground_count(&self) -> usize {
        self.labels.iter().filter(|&&l| l != 0).count()
    }

    /// Voxel count per label (label 0 included), sorted by label.
    #[must_use]
    pub fn histogram(&self) -> Vec<(u16, usize)> {
        let mut counts = vec![0usize; usize::from(u16::MAX) + 1];
        for &l in &self.labels {
            counts[usize::from(l)] += 1;
        }
        counts.iter().enumerate().filter(|&(_, &c)| c > 0).map(|(l, &c)| (l as u16, c)).collect()
    }

    /// Inclusive bounding box `(min, max)` of the non-zero labels, or `None` if all are zero.
    #[must_use]
    pub fn foreground_bounds(&self) -> Option<([usize; 3], [usize; 3])> {
        let [nx, ny, _] = self.dims;
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        // Row by row: only a row's first and last foreground voxels can move the bounds.
        for (r, row) in self.labels.chunks_exact(nx).enumerate() {
            let Some(first) = row.iter().position(|&l| l != 0) else { continue };
            let last = first + row[first..].iter().rposition(|&l| l != 0).unwrap_or(0);
            let (y, z) = (r % ny, r / ny);
            lo = [lo[0].min(first), lo[1].min(y), lo[2].min(z)];
            hi = [hi[0].max(last), hi[1].max(y), hi[2].max(z)];
        }
        (lo[0] != usize::MAX).then_some((lo, hi))
    }

    /// The sub-box `[min, max]` (inclusive) sampled every `stride[a]` voxels along axis `a`, starting
    /// at `min`. The spacing grows by the stride and the origin moves to the first sample.
    pub fn sub_volume(
        &self,
        min: [usize; 3],
        max: [usize; 3],
        stride: [usize; 3],
    ) -> Result<Self, VolumeError> {
        for a in 0..3 {
            if stride[a] == 0 {
                return Err(VolumeError::BadStride { axis: a });
            }
            if min[a] > max[a] || max[a] >= self.dims[a] {
                return Err(VolumeError::BadCrop {
                    axis: a,
                    min: min[a],
                    max: max[a],
                    dim: self.dims[a],
                });
            }
        }
        let dims: [usize; 3] = std::array::from_fn(|a| (max[a] - min[a]) / stride[a] + 1);
        let mut labels = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                let row = self.index(min[0], min[1] + y * stride[1], min[2] + z * stride[2]);
                labels.extend((0..dims[0]).map(|x| self.labels[row + x * stride[0]]));
            }
        }
        let spacing = std::array::from_fn(|a| self.spacing[a] * stride[a] as f64);
        let origin = self.world_from_voxel([min[0] as f64, min[1] as f64, min[2] as f64]);
        Self::new(dims, spacing, labels)?.with_placement(origin, self.direction)
    }

    /// Crops to the foreground's bounding box and keeps every `stride[a]`-th voxel along axis `a`
    /// (`[1, 1, 1]` only crops). The liver fixture at stride `[4, 4, 2]` gives 84×70×68 voxels.
    pub fn crop_and_stride(&self, stride: [usize; 3]) -> Result<Self, VolumeError> {
        let (lo, hi) = self.foreground_bounds().ok_or(VolumeError::EmptyForeground)?;
        let out = self.sub_volume(lo, hi, stride)?;
        if out.foreground_count() == 0 {
            return Err(VolumeError::EmptyForeground);
        }
        Ok(out)
    }

    /// Only the largest face-connected piece of foreground (striding a segmentation can leave
    /// isolated voxels behind, which would float free in a simulation). Ties go to the piece with
    /// the smallest voxel index.
    #[must_use]
    pub fn largest_component(&self) -> Self {
        let [nx, ny, nz] = self.dims;
        let n = self.labels.len();
        let mut component = vec![u32::MAX; n];
        let mut sizes: Vec<usize> = Vec::new();
        let mut stack = Vec::new();
        for start in 0..n {
            if self.labels[start] == 0 || component[start] != u32::MAX {
                continue;
            }
            let id = sizes.len() as u32;
            component[start] = id;
            stack.push(start);
            let mut size = 0;
            while let Some(i) = stack.pop() {
                size += 1;
                let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
                let neighbours = [
                    (x > 0).then(|| i - 1),
                    (x + 1 < nx).then(|| i + 1),
                    (y > 0).then(|| i - nx),
                    (y + 1 < ny).then(|| i + nx),
                    (z > 0).then(|| i - nx * ny),
                    (z + 1 < nz).then(|| i + nx * ny),
                ];
                for j in neighbours.into_iter().flatten() {
                    if self.labels[j] != 0 && component[j] == u32::MAX {
                        component[j] = id;
                        stack.push(j);
                    }
                }
            }
            sizes.push(size);
        }
        let mut out = self.clone();
        if let Some(best) = (0..sizes.len()).max_by_key(|&k| (sizes[k], std::cmp::Reverse(k))) {
            for (l, &c) in out.labels.iter_mut().zip(&component) {
                if c != best as u32 {
                    *l = 0;
                }
            }
        }
        out
    }

    /// Rewrites labels through `filter` (dropping, keeping or merging labels).
    #[must_use]
    pub fn filtered(&self, filter: &crate::material::LabelFilter) -> Self {
        // One filter lookup per label value, not per voxel: a CT holds tens of millions of voxels
        // and a handful of labels.
        let table: Vec<u16> = (0..=u16::MAX).map(|l| filter.apply(l)).collect();
        Self {
            dims: self.dims,
            spacing: self.spacing,
            origin: self.origin,
            direction: self.direction,
            labels: self.labels.iter().map(|&l| table[usize::from(l)]).collect(),
        }
    }

    /// World position (metres) of a point given in voxel coordinates (voxel centres at integers).
    #[must_use]
    pub fn world_from_voxel(&self, p: Vec3) -> Vec3 {
        let s = [p[0] * self.spacing[0], p[1] * self.spacing[1], p[2] * self.spacing[2]];
        std::array::from_fn(|r| {
            self.origin[r]
                + self.direction[r][0] * s[0]
                + self.direction[r][1] * s[1]
                + self.direction[r][2] * s[2]
        })
    }
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The row-wise bounds and the table-driven filter give what a voxel-by-voxel pass gives.
        #[test]
        fn bounds_and_filter_equal_a_voxel_by_voxel_pass(
            dims in prop::array::uniform3(1usize..9),
            seed in any::<u64>(),
            fill in 0u64..4,
        ) {
            let n = dims[0] * dims[1] * dims[2];
            let mut s = seed | 1;
            let labels: Vec<u16> = (0..n)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    // `fill` of 4 voxels carry a label, from a few values incl. merged ones.
                    if s % 4 < fill { [84, 85, 127, 255][(s >> 8) as usize % 4] } else { 0 }
                })
                .collect();
            let v = LabelVolume::new(dims, [1e-3; 3], labels.clone()).unwrap();
            let mut lo = [usize::MAX; 3];
            let mut hi = [0usize; 3];
            for (i, &l) in labels.iter().enumerate() {
                if l != 0 {
                    let p = [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])];
                    for a in 0..3 {
                        lo[a] = lo[a].min(p[a]);
                        hi[a] = hi[a].max(p[a]);
                    }
                }
            }
            prop_assert_eq!(v.foreground_bounds(), (lo[0] != usize::MAX).then_some((lo, hi)));
            let filter = crate::material::LabelFilter::all().merge(84, 85).keep(&[85, 255]);
            let f = v.filtered(&filter);
            let want: Vec<u16> = labels.iter().map(|&l| filter.apply(l)).collect();
            prop_assert_eq!(f.labels(), &want[..]);
            prop_assert_eq!(f.dims(), v.dims());
        }
    }

    fn tiny() -> LabelVolume {
        // 4×3×2 with a 2×2×1 foreground block at x 1..=2, y 1..=2, z 1.
        let mut labels = vec![0u16; 24];
        for (x, y) in [(1, 1), (2, 1), (1, 2), (2, 2)] {
            labels[x + 4 * (y + 3)] = 7;
        }
        LabelVolume::new([4, 3, 2], [1e-3, 2e-3, 3e-3], labels).unwrap()
    }

    #[test]
    #[allow(clippy::float_cmp)] // exact: spacing times a small integer, added to a zero origin
    fn crop_finds_the_block_and_moves_the_origin() {
        let v = tiny().crop_and_stride([1, 1, 1]).unwrap();
        assert_eq!(v.dims(), [2, 2, 1]);
        assert_eq!(v.foreground_count(), 4);
        assert_eq!(v.origin(), [1e-3, 2e-3, 3e-3]);
    }

    #[test]
    #[allow(clippy::float_cmp)] // exact: doubling a double is exact
    fn stride_scales_spacing() {
        let v = tiny().crop_and_stride([2, 1, 1]).unwrap();
        assert_eq!(v.dims(), [1, 2, 1]);
        assert_eq!(v.spacing(), [2e-3, 2e-3, 3e-3]);
    }

    #[test]
    fn largest_component_drops_stray_voxels() {
        let mut labels = vec![1u16; 27];
        labels[0] = 0;
        labels[1] = 0;
        labels[3] = 0;
        labels[9] = 0; // voxel 0's neighbours are empty...
        labels[0] = 2; // ...so a label-2 voxel at 0 is a piece of its own
        let v = LabelVolume::new([3, 3, 3], [1.0; 3], labels).unwrap();
        let kept = v.largest_component();
        assert_eq!(kept.label(0, 0, 0), 0);
        assert_eq!(kept.foreground_count(), v.foreground_count() - 1);
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(matches!(
            LabelVolume::new([0, 1, 1], [1.0; 3], vec![]),
            Err(VolumeError::BadDimension { axis: 0, .. })
        ));
        assert!(matches!(
            LabelVolume::new([1, 1, 1], [1.0, 0.0, 1.0], vec![1]),
            Err(VolumeError::BadSpacing { axis: 1, .. })
        ));
        assert!(matches!(
            LabelVolume::new([2, 1, 1], [1.0; 3], vec![1]),
            Err(VolumeError::SizeMismatch { .. })
        ));
        let empty = LabelVolume::new([2, 1, 1], [1.0; 3], vec![0, 0]).unwrap();
        assert!(matches!(empty.crop_and_stride([1, 1, 1]), Err(VolumeError::EmptyForeground)));
        assert!(matches!(
            tiny().crop_and_stride([1, 0, 1]),
            Err(VolumeError::BadStride { axis: 1 })
        ));
    }
}
