//! Smoothing of the rest positions (paper 1, §3: "The marching cubes algorithm often produces
//! sharp edges meshes. We smooth the surfaces ..."). Taubin's λ|μ filter moves each vertex towards
//! the mean of its neighbours and back out, so the surface loses its voxel steps without shrinking.
//! Each vertex is then clamped to its owner voxel's box grown by half a voxel: it stays next to
//! the voxel whose element carries it, so the embedding remains valid ("displacing the vertices of
//! the triangles with a smoothing algorithm is not problematic for the other operations").

use crate::extract::Surface;
use incise_math::Vec3;

/// Taubin's pass-band parameter: frequencies below it pass, the voxel steps above it are damped.
const PASS_BAND: f64 = 0.1;

impl Surface {
    /// Rest positions of every vertex slot after `iterations` Taubin λ|μ steps with factor
    /// `lambda` (in `(0, 1)`; `μ = 1 / (k_PB − 1/λ)` with `k_PB = 0.1`), each vertex kept in its
    /// owner voxel's box grown by half a voxel. Free slots keep their last position.
    #[must_use]
    pub fn smoothed_rest(&self, iterations: usize, lambda: f64) -> Vec<Vec3> {
        let n = self.vertices().len();
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (_, t) in self.live_triangles() {
            for i in 0..3 {
                let (a, b) = (t.v[i], t.v[(i + 1) % 3]);
                neighbours[a as usize].push(b);
                neighbours[b as usize].push(a);
            }
        }
        for list in &mut neighbours {
            list.sort_unstable();
            list.dedup();
        }
        let h = self.spacing();
        let dims = self.dims();
        let bounds: Vec<(Vec3, Vec3)> = self
            .vertices()
            .iter()
            .map(|v| {
                let x = [
                    v.voxel % dims[0],
                    (v.voxel / dims[0]) % dims[1],
                    v.voxel / (dims[0] * dims[1]),
                ];
                let lo = std::array::from_fn(|a| (f64::from(x[a]) - 0.5) * h[a]);
                let hi = std::array::from_fn(|a| (f64::from(x[a]) + 1.5) * h[a]);
                (lo, hi)
            })
            .collect();
        let mu = 1.0 / (PASS_BAND - 1.0 / lambda);
        let mut p = self.rest_positions();
        let mut next = p.clone();
        for _ in 0..iterations {
            for factor in [lambda, mu] {
                for (i, list) in neighbours.iter().enumerate() {
                    if list.is_empty() {
                        continue;
                    }
                    let k = list.len() as f64;
                    let (lo, hi) = bounds[i];
                    next[i] = std::array::from_fn(|a| {
                        let mean = list.iter().map(|&j| p[j as usize][a]).sum::<f64>() / k;
                        (p[i][a] + factor * (mean - p[i][a])).clamp(lo[a], hi[a])
                    });
                }
                std::mem::swap(&mut p, &mut next);
            }
        }
        p
    }

    /// Sets the rest position of every live vertex from `positions` (indexed by slot, e.g. from
    /// [`Surface::smoothed_rest`]), clamped to the owner voxel's box grown by half a voxel,  so that
    /// a [`crate::SurfaceMapping`] embeds the smoothed surface. Vertices a later
    /// [`Surface::remesh`] creates start at their voxel face centres.
    ///
    /// # Panics
    /// If `positions` is shorter than the vertex slots.
    pub fn set_rest(&mut self, positions: &[Vec3]) {
        assert!(positions.len() >= self.vertices.len(), "one position per vertex slot");
        for i in 0..self.vertices.len() {
            if self.vertices[i].alive {
                let (lo, hi) = self.owner_box(self.vertices[i].voxel);
                self.vertices[i].rest =
                    std::array::from_fn(|a| positions[i][a].clamp(lo[a], hi[a]));
            }
        }
    }

    /// The box of voxel `v` grown by half a voxel on every side: where its vertices may move
    /// without leaving the elements around their owner.
    fn owner_box(&self, v: u32) -> (Vec3, Vec3) {
        let (h, d) = (self.spacing(), self.dims());
        let x = [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])];
        let lo = std::array::from_fn(|a| (f64::from(x[a]) - 0.5) * h[a]);
        let hi = std::array::from_fn(|a| (f64::from(x[a]) + 1.5) * h[a]);
        (lo, hi)
    }
}
