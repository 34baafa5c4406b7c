//! A geometric nested-dissection ordering of mesh nodes for the sparse Cholesky factor.
//!
//! On a 3-D grid, minimum-degree orderings leave much more fill than nested dissection (George
//! 1973): the factor of an n×n×n grid has O(n⁴) entries with dissection, and the triangular solves
//! that precondition CG are bound by reading those entries. The grid's nodes sit on lattice planes
//! and every hexahedron spans two neighbouring planes, so one plane of nodes is a separator; it is
//! found from the rest positions, and any edge still crossing it is closed by moving its left end
//! into the separator, so the result is a valid dissection on any mesh.

use incise_math::Vec3;

/// Subsets at most this large are ordered as they come: a dense block this size factorises fast.
const LEAF: usize = 8;

/// A nested-dissection order.
pub struct Dissection {
    /// The nodes in elimination order: each half before the separator that splits it from its
    /// sibling.
    pub order: Vec<u32>,
    /// Where the top level's two halves end in `order` (the top separator follows), if the set
    /// was split at all.
    pub halves: Option<[usize; 2]>,
}

/// The nodes `0..positions.len()` in nested-dissection order. `adjacent[i]` lists the nodes sharing
/// an element with node `i` (in either direction; both are checked).
#[must_use]
pub fn nested_dissection(positions: &[Vec3], adjacent: &[Vec<u32>]) -> Dissection {
    let mut halves = None;
    let n = positions.len();
    let mut order = Vec::with_capacity(n);
    // side[i]: which part of the current split node i is in (0 left, 1 right, 2 separator).
    let mut side = vec![0u8; n];
    let mut stack: Vec<(Vec<u32>, bool)> = vec![((0..n as u32).collect(), false)];
    // Iterative post-order: a set is split, then pushed back as "emit separator" after its halves.
    while let Some((nodes, emit)) = stack.pop() {
        if emit || nodes.len() <= LEAF {
            order.extend_from_slice(&nodes);
            continue;
        }
        let (left, right, separator) = split(&nodes, positions, adjacent, &mut side);
        if left.is_empty() || right.is_empty() {
            // No plane splits this set (all nodes on one plane, or one big separator).
            order.extend_from_slice(&nodes);
            continue;
        }
        if halves.is_none() {
            halves = Some([left.len(), left.len() + right.len()]);
        }
        stack.push((separator, true));
        stack.push((right, false));
        stack.push((left, false));
    }
    debug_assert_eq!(order.len(), n);
    Dissection { order, halves }
}

/// Splits `nodes` across the median lattice plane of their longest axis.
fn split(
    nodes: &[u32],
    positions: &[Vec3],
    adjacent: &[Vec<u32>],
    side: &mut [u8],
) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in nodes {
        for a in 0..3 {
            lo[a] = lo[a].min(positions[i as usize][a]);
            hi[a] = hi[a].max(positions[i as usize][a]);
        }
    }
    let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
    let mut coords: Vec<f64> = nodes.iter().map(|&i| positions[i as usize][axis]).collect();
    coords.sort_unstable_by(f64::total_cmp);
    let median = coords[coords.len() / 2];
    // Nodes on one lattice plane share the coordinate up to rounding of the grid spacing.
    let tolerance = 1e-9 * (hi[axis] - lo[axis]).max(f64::MIN_POSITIVE);
    for &i in nodes {
        let c = positions[i as usize][axis];
        side[i as usize] = if (c - median).abs() <= tolerance { 2 } else { u8::from(c > median) };
    }
    // Close any edge from left to right (only on meshes that are not lattice-aligned).
    for &i in nodes {
        if side[i as usize] == 0 && adjacent[i as usize].iter().any(|&j| side[j as usize] == 1) {
            side[i as usize] = 2;
        }
    }
    let mut parts = (Vec::new(), Vec::new(), Vec::new());
    for &i in nodes {
        match side[i as usize] {
            0 => parts.0.push(i),
            1 => parts.1.push(i),
            _ => parts.2.push(i),
        }
    }
    // Nodes outside this set keep no stale marks that a later sibling split could read.
    for &i in nodes {
        side[i as usize] = 0;
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice(n: [usize; 3]) -> (Vec<Vec3>, Vec<Vec<u32>>) {
        let id = |x: usize, y: usize, z: usize| (x + n[0] * (y + n[1] * z)) as u32;
        let mut positions = Vec::new();
        let mut adjacent = Vec::new();
        for z in 0..n[2] {
            for y in 0..n[1] {
                for x in 0..n[0] {
                    positions.push([x as f64 * 0.1, y as f64 * 0.1, z as f64 * 0.1]);
                    let mut list = Vec::new();
                    for (dx, dy, dz) in neighbour_offsets() {
                        let (a, b, c) = (x as i64 + dx, y as i64 + dy, z as i64 + dz);
                        if (0..n[0] as i64).contains(&a)
                            && (0..n[1] as i64).contains(&b)
                            && (0..n[2] as i64).contains(&c)
                        {
                            list.push(id(a as usize, b as usize, c as usize));
                        }
                    }
                    adjacent.push(list);
                }
            }
        }
        (positions, adjacent)
    }

    fn neighbour_offsets() -> impl Iterator<Item = (i64, i64, i64)> {
        (-1..=1).flat_map(|a| (-1..=1).flat_map(move |b| (-1..=1).map(move |c| (a, b, c))))
    }

    #[test]
    fn the_order_is_a_permutation_and_each_separator_follows_its_halves() {
        let (positions, adjacent) = lattice([9, 7, 6]);
        let Dissection { order, halves } = nested_dissection(&positions, &adjacent);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..positions.len() as u32).collect::<Vec<_>>());
        // Halves of 4 and 4 planes of 7 × 6 nodes, split at x = 4.
        assert_eq!(halves, Some([4 * 42, 8 * 42]));
        for (k, &i) in order.iter().enumerate() {
            let x = positions[i as usize][0];
            let expected = if k < 4 * 42 {
                x < 0.35
            } else if k < 8 * 42 {
                x > 0.45
            } else {
                (x - 0.4).abs() < 1e-12
            };
            assert!(expected, "node {i} at {x} ordered {k}");
        }
        // The last node ordered is in the top separator: the plane that halves the longest axis.
        let last = order[order.len() - 1] as usize;
        assert!((positions[last][0] - 0.4).abs() < 1e-12, "{:?}", positions[last]);
    }

    #[test]
    fn a_mesh_that_is_not_lattice_aligned_still_gets_a_valid_separator() {
        let (mut positions, adjacent) = lattice([8, 3, 3]);
        for (i, p) in positions.iter_mut().enumerate() {
            p[0] += 0.03 * ((i * 7919) % 5) as f64;
        }
        let order = nested_dissection(&positions, &adjacent).order;
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen.len(), positions.len());
        seen.dedup();
        assert_eq!(seen.len(), positions.len());
    }
}
