//! Fixed nodes, applied by projection: a fixed node's velocity and displacement stay zero, its
//! rows and columns of the system are replaced by the identity, its residual by zero.

use incise_math::Vec3;

/// Which nodes are held in place.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FixedNodes {
    fixed: Vec<bool>,
}

impl FixedNodes {
    /// No node fixed, for `nodes` nodes.
    #[must_use]
    pub fn none(nodes: usize) -> Self {
        Self { fixed: vec![false; nodes] }
    }

    /// The nodes in `list` (indices below `nodes`; repeats are fine).
    ///
    /// # Panics
    /// If an index is not below `nodes`.
    #[must_use]
    pub fn from_list(nodes: usize, list: &[usize]) -> Self {
        let mut fixed = vec![false; nodes];
        for &n in list {
            fixed[n] = true;
        }
        Self { fixed }
    }

    /// Nodes whose rest position satisfies `inside`.
    #[must_use]
    pub fn by_position(rest: &[Vec3], inside: impl Fn(&Vec3) -> bool) -> Self {
        Self { fixed: rest.iter().map(inside).collect() }
    }

    /// Nodes within `tolerance` of the plane `x[axis] = value`.
    #[must_use]
    pub fn plane(rest: &[Vec3], axis: usize, value: f64, tolerance: f64) -> Self {
        Self::by_position(rest, |p| (p[axis] - value).abs() <= tolerance)
    }

    /// Nodes inside the axis-aligned box `[lo, hi]`.
    #[must_use]
    pub fn aabb(rest: &[Vec3], lo: Vec3, hi: Vec3) -> Self {
        Self::by_position(rest, |p| (0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a]))
    }

    /// Also holds node `n`.
    #[must_use]
    pub fn with(mut self, n: usize) -> Self {
        self.fixed[n] = true;
        self
    }

    /// Adds the nodes of `other`.
    #[must_use]
    pub fn union(mut self, other: &Self) -> Self {
        for (a, b) in self.fixed.iter_mut().zip(&other.fixed) {
            *a |= *b;
        }
        self
    }

    /// True when node `n` is fixed.
    #[inline]
    #[must_use]
    pub fn is_fixed(&self, n: usize) -> bool {
        self.fixed[n]
    }

    /// Number of nodes (fixed or free) this set describes.
    #[must_use]
    pub fn node_count(&self) -> usize {
        self.fixed.len()
    }

    /// Number of fixed nodes.
    #[must_use]
    pub fn count(&self) -> usize {
        self.fixed.iter().filter(|&&f| f).count()
    }

    /// How far `f` (the net force per node) is from equilibrium: the largest force component on a
    /// free node over the largest on a fixed one (the reaction). Infinite when a force is not
    /// finite (`max` would skip a NaN).
    #[must_use]
    pub fn residual_ratio(&self, f: &[Vec3]) -> f64 {
        let (mut free, mut held) = (0.0f64, 0.0f64);
        for (fi, &fixed) in f.iter().zip(&self.fixed) {
            if fi.iter().any(|c| !c.is_finite()) {
                return f64::INFINITY;
            }
            let m = fi.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            if fixed { held = held.max(m) } else { free = free.max(m) }
        }
        free / held.max(f64::MIN_POSITIVE)
    }

    /// Zeroes the fixed nodes' entries of `v`.
    pub fn project(&self, v: &mut [Vec3]) {
        for (x, &f) in v.iter_mut().zip(&self.fixed) {
            if f {
                *x = [0.0; 3];
            }
        }
    }
}
