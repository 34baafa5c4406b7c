//! The tensor-mass form of linear and St Venant-Kirchhoff elasticity (paper 2 §3, eq. 7–10).
//!
//! Expanding the energy of a tetrahedron in the vertex displacements `Uⱼ` gives (eq. 7)
//!
//! `W = Σⱼₖ Uⱼᵀ Bⱼₖ Uₖ + Σⱼₖₗ (Uⱼ · Cⱼₖₗ)(Uₖ · Uₗ) + Σⱼₖₗₘ Dⱼₖₗₘ (Uⱼ · Uₖ)(Uₗ · Uₘ)`
//!
//! with, for shape vectors `αⱼ` and `sⱼₖ = αⱼ · αₖ` (eq. 8, times the rest volume `V₀`, which
//! the paper folds into its notation):
//! - `Bⱼₖ = V₀ (λ/2 αⱼ ⊗ αₖ + μ/2 (αₖ ⊗ αⱼ + sⱼₖ I))` (3×3; the linear model is this term alone),
//! - `Cⱼₖₗ = V₀ (λ/2 αⱼ sₖₗ + μ/2 (αₗ sⱼₖ + αₖ sⱼₗ))` (a vector),
//! - `Dⱼₖₗₘ = V₀ (λ/8 sⱼₖ sₗₘ + μ/4 sₖₗ sⱼₘ)` (a scalar).
//!
//! Summed over the tetrahedra around them (eq. 10), the terms live on the mesh's simplices: a
//! term's vertex set is a vertex, an edge, a triangle or a tetrahedron. Terms are stored in
//! canonical form (`Cⱼₖₗ` symmetrised in `k, l`; `Dⱼₖₗₘ` in `j, k`, in `l, m` and between the
//! pairs) and grouped by simplex (vertices first, then edges, triangles, tetrahedra), and each
//! term counts the tetrahedra that contribute to it. Removing a tetrahedron subtracts its own
//! terms (recomputed from its rest shape, bit-identical to what was added) and sets a term whose
//! last contributor is gone to exactly zero. The force on vertex `p` is `−∂W/∂Uₚ`.

use super::element::{Elasticity, TetModel};
use incise_math::Vec3;
use incise_math::mat3::{Mat3, dot, mul_transpose_vec, mul_vec};
use incise_mesh::TetTopology;
use incise_mesh::topology::EDGES;
use std::collections::{BTreeMap, HashMap};

/// One tetrahedron's terms in canonical form (global vertex ids).
#[derive(Default)]
struct TetTerms {
    vertex: Vec<(u32, Mat3)>,
    /// `(edge id, lower vertex, M)` with energy `U_lowᵀ M U_high`.
    edge: Vec<(u32, Mat3)>,
    cubic: BTreeMap<[u32; 3], Vec3>,
    quartic: BTreeMap<[u32; 4], f64>,
}

fn sorted2(a: u32, b: u32) -> [u32; 2] {
    if a <= b { [a, b] } else { [b, a] }
}

/// The terms of tetrahedron `t` (only `B` for the linear model).
fn tet_terms(model: &TetModel, topo: &TetTopology, t: usize, kind: Elasticity) -> TetTerms {
    let a = &model.shape[t];
    let v = model.volume[t];
    let (lambda, mu) = (model.lame[t].lambda, model.lame[t].mu);
    let g = model.tets[t];
    let s: [[f64; 4]; 4] = std::array::from_fn(|j| std::array::from_fn(|k| dot(&a[j], &a[k])));
    // Transverse isotropy (paper 2 §3): κ (a₀ᵀEa₀)² with βⱼ = αⱼ · a₀ adds V₀κ βⱼβₖ a₀ ⊗ a₀ to
    // Bⱼₖ, V₀κ βⱼβₖβₗ a₀ to Cⱼₖₗ and V₀κ/4 βⱼβₖβₗβₘ to Dⱼₖₗₘ.
    let (a0, kappa) = model.fibre[t].unwrap_or(([0.0; 3], 0.0));
    let beta: [f64; 4] = std::array::from_fn(|j| dot(&a[j], &a0));
    let b = |j: usize, k: usize| -> Mat3 {
        std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                let delta = if r == c { s[j][k] } else { 0.0 };
                v * (0.5 * lambda * a[j][r] * a[k][c]
                    + 0.5 * mu * (a[k][r] * a[j][c] + delta)
                    + kappa * beta[j] * beta[k] * a0[r] * a0[c])
            })
        })
    };
    let mut out = TetTerms::default();
    for j in 0..4 {
        out.vertex.push((g[j], b(j, j)));
    }
    for (e, &[j, k]) in EDGES.iter().enumerate() {
        // Bⱼₖ + Bₖⱼᵀ = 2 Bⱼₖ, oriented from the lower global vertex.
        let (lo, hi) = if g[j] < g[k] { (j, k) } else { (k, j) };
        let m = b(lo, hi).map(|row| row.map(|x| 2.0 * x));
        out.edge.push((topo.tet_edges(t)[e], m));
    }
    if kind == Elasticity::Linear {
        return out;
    }
    for j in 0..4 {
        for k in 0..4 {
            for l in 0..4 {
                let c: Vec3 = std::array::from_fn(|r| {
                    v * (0.5 * lambda * a[j][r] * s[k][l]
                        + 0.5 * mu * (a[l][r] * s[j][k] + a[k][r] * s[j][l])
                        + kappa * beta[j] * beta[k] * beta[l] * a0[r])
                });
                let [lo, hi] = sorted2(g[k], g[l]);
                let entry = out.cubic.entry([g[j], lo, hi]).or_insert([0.0; 3]);
                for r in 0..3 {
                    entry[r] += c[r];
                }
                for m in 0..4 {
                    let d = v
                        * (0.125 * lambda * s[j][k] * s[l][m]
                            + 0.25 * mu * s[k][l] * s[j][m]
                            + 0.25 * kappa * beta[j] * beta[k] * beta[l] * beta[m]);
                    let (p, q) = (sorted2(g[j], g[k]), sorted2(g[l], g[m]));
                    let (first, second) = if p <= q { (p, q) } else { (q, p) };
                    *out.quartic
                        .entry([first[0], first[1], second[0], second[1]])
                        .or_insert(0.0) += d;
                }
            }
        }
    }
    out
}

/// Sort key grouping terms by simplex: (vertex count, the sorted distinct vertices, the term).
fn simplex_key<const N: usize>(key: &[u32; N]) -> (usize, [u32; 4], [u32; N]) {
    let mut set = [u32::MAX; 4];
    let mut n = 0;
    let mut sorted = key.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    for (i, &x) in sorted.iter().enumerate() {
        set[i] = x;
        n += 1;
    }
    (n, set, *key)
}

/// Terms keyed for grouping by simplex ([`simplex_key`]), with their sums and contributor counts.
type Accumulated<const N: usize, T> = BTreeMap<(usize, [u32; 4], [u32; N]), (T, u32)>;

/// Terms of one polynomial degree, grouped by simplex, with their contributor counts.
#[derive(Clone, Debug, Default)]
struct TermTable<const N: usize, T> {
    keys: Vec<[u32; N]>,
    values: Vec<T>,
    contributors: Vec<u32>,
    index: HashMap<[u32; N], u32>,
}

impl<const N: usize, T: Copy + Default> TermTable<N, T> {
    fn build(all: Accumulated<N, T>) -> Self {
        let mut table = Self::default();
        for ((_, _, key), (value, count)) in all {
            table.index.insert(key, table.keys.len() as u32);
            table.keys.push(key);
            table.values.push(value);
            table.contributors.push(count);
        }
        table
    }

    /// Adds one contributor's `value` to `key` (a key of the table).
    fn add(&mut self, key: &[u32; N], value: T, add: impl Fn(&mut T, &T)) {
        let i = self.index[key] as usize;
        self.contributors[i] += 1;
        add(&mut self.values[i], &value);
    }

    /// Sets every value and count to zero (no contributor).
    fn clear(&mut self) {
        self.values.fill(T::default());
        self.contributors.fill(0);
    }

    /// Subtracts one contributor's `value` from `key` (zero exactly when none is left).
    fn remove(&mut self, key: &[u32; N], value: T, sub: impl Fn(&mut T, &T)) {
        let i = self.index[key] as usize;
        self.contributors[i] -= 1;
        if self.contributors[i] == 0 {
            self.values[i] = T::default();
        } else {
            sub(&mut self.values[i], &value);
        }
    }
}

/// Linear or St Venant-Kirchhoff elasticity stored on vertices, edges, triangles and tetrahedra.
#[derive(Clone, Debug)]
pub struct TensorMassForceField {
    kind: Elasticity,
    /// `Σ Bₚₚ` per vertex.
    vertex_b: Vec<Mat3>,
    /// `Σ (Bₐᵦ + Bᵦₐᵀ)` per edge, oriented from its lower vertex.
    edge_b: Vec<Mat3>,
    edge_vertices: Vec<[u32; 2]>,
    cubic: TermTable<3, Vec3>,
    quartic: TermTable<4, f64>,
    /// Per cubic term `(Uⱼ · c)(Uₖ · Uₗ)`, the pair `{k, l}` (see [`Pairs`]).
    cubic_pair: Vec<u32>,
    /// Per quartic term `d (Uₐ · Uᵦ)(U꜀ · Uₔ)`, its two pairs.
    quartic_pairs: Vec<[u32; 2]>,
    /// Adaptive non-linearity (paper 2 §6), when on.
    adaptive: Option<AdaptiveState>,
    /// The threads its two term parts run on.
    exec: crate::exec::Executor,
}

/// Adaptive non-linearity (paper 2 §6): which vertices are non-linear, and which tetrahedra
/// (those with a non-linear vertex) have their cubic and quartic terms in the tables.
#[derive(Clone, Debug)]
struct AdaptiveState {
    threshold: f64,
    hysteresis: f64,
    flags: Vec<bool>,
    /// How many of `flags` are set, kept as they flip (read every step).
    nonlinear: usize,
    /// Tetrahedra of each vertex.
    vertex_tets: Vec<Vec<u32>>,
    /// Non-linear vertices of each tetrahedron.
    tet_count: Vec<u8>,
    /// Tetrahedra whose non-linear state changed since the tables were last updated.
    changed: Vec<u32>,
    /// Per table (0 cubic, 1 quartic): the terms with a contributor, in table order.
    active: [Vec<u32>; 2],
}

/// The term tables are evaluated in this many fixed parts (each into its own buffer, summed in
/// order), whatever the number of threads.
const PARTS: usize = 2;

/// Below this many cubic and quartic terms one thread does both parts (a thread hand-off costs
/// more than half the work).
const PARALLEL_TERMS: usize = 20_000;

/// Term indices to visit (see [`TensorMassForceField::terms`]).
enum Terms<'a> {
    All(std::ops::Range<usize>),
    Active(std::slice::Iter<'a, u32>),
}

impl Iterator for Terms<'_> {
    type Item = usize;

    #[inline]
    fn next(&mut self) -> Option<usize> {
        match self {
            Terms::All(r) => r.next(),
            Terms::Active(it) => it.next().map(|&i| i as usize),
        }
    }
}

/// Indices of part `part` of `0..n`.
fn part_range(n: usize, part: usize) -> std::ops::Range<usize> {
    let size = n.div_ceil(PARTS);
    (part * size).min(n)..((part + 1) * size).min(n)
}

/// `x − rest` per vertex.
fn displacements(model: &TetModel, x: &[Vec3]) -> Vec<Vec3> {
    x.iter().zip(&model.rest).map(|(p, r)| [p[0] - r[0], p[1] - r[1], p[2] - r[2]]).collect()
}

fn add3(a: &mut Mat3, b: &Mat3, sign: f64) {
    for r in 0..3 {
        for c in 0..3 {
            a[r][c] += sign * b[r][c];
        }
    }
}

impl TensorMassForceField {
    /// The same field running its two term parts on `exec` (the simulation's executor).
    #[must_use]
    pub fn with_executor(mut self, exec: crate::exec::Executor) -> Self {
        self.exec = exec;
        self
    }

    /// The executor its two term parts run on.
    #[must_use]
    pub fn executor(&self) -> &crate::exec::Executor {
        &self.exec
    }

    /// Precomputes the stiffness tensors of every live tetrahedron of `topo`.
    #[must_use]
    pub fn new(model: &TetModel, topo: &TetTopology, kind: Elasticity) -> Self {
        let mut vertex_b = vec![[[0.0; 3]; 3]; model.vertex_count()];
        let mut edge_b = vec![[[0.0; 3]; 3]; topo.edges().len()];
        let mut cubic: Accumulated<3, Vec3> = BTreeMap::new();
        let mut quartic: Accumulated<4, f64> = BTreeMap::new();
        for t in (0..model.tets.len()).filter(|&t| topo.is_alive(t)) {
            let terms = tet_terms(model, topo, t, kind);
            for (n, m) in &terms.vertex {
                add3(&mut vertex_b[*n as usize], m, 1.0);
            }
            for (e, m) in &terms.edge {
                add3(&mut edge_b[*e as usize], m, 1.0);
            }
            for (key, c) in terms.cubic {
                let entry = cubic.entry(simplex_key(&key)).or_insert(([0.0; 3], 0));
                for r in 0..3 {
                    entry.0[r] += c[r];
                }
                entry.1 += 1;
            }
            for (key, d) in terms.quartic {
                let entry = quartic.entry(simplex_key(&key)).or_insert((0.0, 0));
                entry.0 += d;
                entry.1 += 1;
            }
        }
        let mut field = Self {
            kind,
            vertex_b,
            edge_b,
            edge_vertices: topo.edges().to_vec(),
            cubic_pair: Vec::new(),
            quartic_pairs: Vec::new(),
            cubic: TermTable::build(cubic),
            quartic: TermTable::build(quartic),
            adaptive: None,
            exec: crate::exec::Executor::default(),
        };
        let edge_of: HashMap<[u32; 2], u32> =
            topo.edges().iter().enumerate().map(|(i, &e)| (e, i as u32)).collect();
        let vertices = field.vertex_b.len() as u32;
        let pair =
            |a: u32, b: u32| -> u32 { if a == b { a } else { vertices + edge_of[&sorted2(a, b)] } };
        field.cubic_pair = field.cubic.keys.iter().map(|&[_, k, l]| pair(k, l)).collect();
        field.quartic_pairs =
            field.quartic.keys.iter().map(|&[a, b, c, e]| [pair(a, b), pair(c, e)]).collect();
        field
    }

    /// Cuts tetrahedron `t` out of `topo` ([`TetTopology::cut`]: with any tetrahedra that would
    /// hang on by an edge or a vertex) and subtracts each removed tetrahedron's stiffness
    /// contributions. Returns the tetrahedra removed (empty when `t` was already removed).
    pub fn remove_tet(&mut self, model: &TetModel, topo: &mut TetTopology, t: usize) -> Vec<usize> {
        let removed = topo.cut(t);
        for &r in &removed {
            self.subtract(model, topo, r);
        }
        // A vertex or edge without live tetrahedra is exactly zero, not a rounding residue.
        for &r in &removed {
            for &n in &model.tets[r] {
                if topo.vertex_degree(n as usize) == 0 {
                    self.vertex_b[n as usize] = [[0.0; 3]; 3];
                }
            }
            for &e in topo.tet_edges(r) {
                if topo.edge_degree(e as usize) == 0 {
                    self.edge_b[e as usize] = [[0.0; 3]; 3];
                }
            }
        }
        if !removed.is_empty() {
            self.refresh_active();
        }
        removed
    }

    /// Subtracts removed tetrahedron `t`'s contributions.
    fn subtract(&mut self, model: &TetModel, topo: &TetTopology, t: usize) {
        let terms = tet_terms(model, topo, t, self.kind);
        for (n, m) in &terms.vertex {
            add3(&mut self.vertex_b[*n as usize], m, -1.0);
        }
        for (e, m) in &terms.edge {
            add3(&mut self.edge_b[*e as usize], m, -1.0);
        }
        // Adaptive: a linear tetrahedron's cubic and quartic terms are not in the tables.
        let in_tables = self.adaptive.as_ref().is_none_or(|a| a.tet_count[t] > 0);
        if in_tables {
            for (key, c) in &terms.cubic {
                self.cubic.remove(key, *c, |a, b| {
                    for r in 0..3 {
                        a[r] -= b[r];
                    }
                });
            }
            for (key, d) in &terms.quartic {
                self.quartic.remove(key, *d, |a, b| *a -= b);
            }
        }
    }

    /// Adaptive: the active term lists from the contributor counts.
    fn refresh_active(&mut self) {
        let active = |contributors: &[u32]| -> Vec<u32> {
            (0..contributors.len() as u32).filter(|&i| contributors[i as usize] > 0).collect()
        };
        let lists = [active(&self.cubic.contributors), active(&self.quartic.contributors)];
        if let Some(a) = self.adaptive.as_mut() {
            a.active = lists;
        }
    }

    /// The model this field evaluates.
    #[must_use]
    pub fn elasticity(&self) -> Elasticity {
        self.kind
    }

    /// Stored terms: (vertex tensors, edge tensors, cubic vectors, quartic scalars).
    #[must_use]
    pub fn term_counts(&self) -> (usize, usize, usize, usize) {
        (self.vertex_b.len(), self.edge_b.len(), self.cubic.keys.len(), self.quartic.keys.len())
    }

    /// `f += elastic forces` at positions `x` (rest positions from `model`). With adaptive
    /// non-linearity on, the cubic and quartic terms are those of the non-linear tetrahedra
    /// ([`TensorMassForceField::update_adaptive`]).
    ///
    /// The non-linear terms are products of the pair products `Uₐ · Uᵦ` over vertices (`a = b`)
    /// and edges: those are computed once, each term adds its coefficient to the pairs it
    /// multiplies (`∂W/∂(Uₐ · Uᵦ)`), and the pairs turn into forces at the end.
    pub fn add_forces(&self, model: &TetModel, x: &[Vec3], f: &mut [Vec3]) {
        let u = displacements(model, x);
        let pairs: Vec<f64> =
            if self.cubic.keys.is_empty() { Vec::new() } else { self.pair_products(&u) };
        self.chunked(f, 1.0, |part, out| self.force_part(&u, &pairs, part, out));
    }

    /// `Uₐ · Uₐ` per vertex, then `Uₐ · Uᵦ` per edge.
    fn pair_products(&self, u: &[Vec3]) -> Vec<f64> {
        let mut p = Vec::with_capacity(u.len() + self.edge_vertices.len());
        p.extend(u.iter().map(|a| dot(a, a)));
        p.extend(self.edge_vertices.iter().map(|&[a, b]| dot(&u[a as usize], &u[b as usize])));
        p
    }

    /// `out += K(x) v`, the tangent stiffness `−∂f/∂x` at positions `x` times `v` (the same
    /// terms as [`TensorMassForceField::add_forces`]).
    pub fn add_stiffness_times(&self, model: &TetModel, x: &[Vec3], v: &[Vec3], out: &mut [Vec3]) {
        self.add_scaled_stiffness_times(model, x, 1.0, v, out);
    }

    /// `out += scale · K(x) v` (see [`TensorMassForceField::add_stiffness_times`]).
    pub fn add_scaled_stiffness_times(
        &self,
        model: &TetModel,
        x: &[Vec3],
        scale: f64,
        v: &[Vec3],
        out: &mut [Vec3],
    ) {
        let u = displacements(model, x);
        self.chunked(out, scale, |part, buf| self.stiffness_part(&u, v, part, buf));
    }

    /// `blocks[n] += K₀_nn`, the rest stiffness's diagonal blocks (the vertex tensors): the
    /// block-Jacobi preconditioner of an implicit step. The non-linear terms are left out; any
    /// symmetric positive definite blocks precondition correctly, and near rest these are the
    /// Jacobian's.
    pub fn add_rest_diagonal_blocks(&self, blocks: &mut [Mat3]) {
        for (block, b) in blocks.iter_mut().zip(&self.vertex_b) {
            for i in 0..3 {
                for j in 0..3 {
                    block[i][j] += b[i][j] + b[j][i];
                }
            }
        }
    }

    /// Runs `work(part, buffer)` for the [`PARTS`] fixed parts of the term tables, on two
    /// threads when the mesh is large enough, and adds the buffers to `out` in part order: the
    /// sums do not depend on the thread count.
    /// `scale` multiplies the parts' sum (1 leaves its bits alone).
    fn chunked(&self, out: &mut [Vec3], scale: f64, work: impl Fn(usize, &mut [Vec3]) + Sync) {
        let n = out.len();
        let mut first = vec![[0.0; 3]; n];
        let mut second = vec![[0.0; 3]; n];
        let terms = self.cubic.keys.len() + self.quartic.keys.len();
        self.exec.join_if(terms >= PARALLEL_TERMS, || work(0, &mut first), || work(1, &mut second));
        for ((o, a), b) in out.iter_mut().zip(&first).zip(&second) {
            for k in 0..3 {
                o[k] += scale * (a[k] + b[k]);
            }
        }
    }

    /// The terms of `table` (0 cubic, 1 quartic) in part `part`, in table order: all of them,
    /// or with adaptive non-linearity only those touching a non-linear vertex.
    fn terms(&self, table: usize, part: usize) -> Terms<'_> {
        let n = if table == 0 { self.cubic.keys.len() } else { self.quartic.keys.len() };
        let range = part_range(n, part);
        match &self.adaptive {
            None => Terms::All(range),
            Some(a) => {
                // The active terms of the same part as without adaptivity, so that with every
                // vertex non-linear the sums are the full model's, bit for bit.
                let active = &a.active[table];
                let lo = active.partition_point(|&i| (i as usize) < range.start);
                let hi = active.partition_point(|&i| (i as usize) < range.end);
                Terms::Active(active[lo..hi].iter())
            }
        }
    }

    /// The part `part` of every table: `out −= ∂W/∂U`.
    fn force_part(&self, u: &[Vec3], pairs: &[f64], part: usize, out: &mut [Vec3]) {
        let sub = |f: &mut Vec3, v: Vec3, scale: f64| {
            for k in 0..3 {
                f[k] -= scale * v[k];
            }
        };
        for n in part_range(self.vertex_b.len(), part) {
            sub(&mut out[n], mul_vec(&self.vertex_b[n], &u[n]), 2.0);
        }
        for e in part_range(self.edge_b.len(), part) {
            let [lo, hi] = self.edge_vertices[e].map(|x| x as usize);
            let m = &self.edge_b[e];
            sub(&mut out[lo], mul_vec(m, &u[hi]), 1.0);
            sub(&mut out[hi], mul_transpose_vec(m, &u[lo]), 1.0);
        }
        if pairs.is_empty() {
            return;
        }
        // ∂W/∂(pair product), accumulated term by term.
        let mut g = vec![0.0; pairs.len()];
        // (Uⱼ · c) Pₖₗ: ∂/∂Uⱼ = c Pₖₗ, ∂/∂Pₖₗ = Uⱼ · c.
        for i in self.terms(0, part) {
            let j = self.cubic.keys[i][0] as usize;
            let c = &self.cubic.values[i];
            let kl = self.cubic_pair[i] as usize;
            sub(&mut out[j], *c, pairs[kl]);
            g[kl] += dot(&u[j], c);
        }
        // d P₁ P₂: ∂/∂P₁ = d P₂, ∂/∂P₂ = d P₁.
        for i in self.terms(1, part) {
            let [p1, p2] = self.quartic_pairs[i].map(|p| p as usize);
            let d = self.quartic.values[i];
            g[p1] += d * pairs[p2];
            g[p2] += d * pairs[p1];
        }
        // ∂Pₐₐ/∂Uₐ = 2Uₐ; ∂Pₐᵦ/∂Uₐ = Uᵦ.
        let vertices = u.len();
        for (a, &ga) in g[..vertices].iter().enumerate() {
            if ga != 0.0 {
                sub(&mut out[a], u[a], 2.0 * ga);
            }
        }
        for (&[a, b], &ge) in self.edge_vertices.iter().zip(&g[vertices..]) {
            if ge != 0.0 {
                let (a, b) = (a as usize, b as usize);
                sub(&mut out[a], u[b], ge);
                sub(&mut out[b], u[a], ge);
            }
        }
    }

    /// The part `part` of every table: `out += (∂²W/∂U²) v`.
    fn stiffness_part(&self, u: &[Vec3], v: &[Vec3], part: usize, out: &mut [Vec3]) {
        let add = |f: &mut Vec3, w: Vec3, scale: f64| {
            for k in 0..3 {
                f[k] += scale * w[k];
            }
        };
        for n in part_range(self.vertex_b.len(), part) {
            add(&mut out[n], mul_vec(&self.vertex_b[n], &v[n]), 2.0);
        }
        for e in part_range(self.edge_b.len(), part) {
            let [lo, hi] = self.edge_vertices[e].map(|x| x as usize);
            let m = &self.edge_b[e];
            add(&mut out[lo], mul_vec(m, &v[hi]), 1.0);
            add(&mut out[hi], mul_transpose_vec(m, &v[lo]), 1.0);
        }
        let mut add_on = |v: usize, w: Vec3, scale: f64| add(&mut out[v], w, scale);
        for i in self.terms(0, part) {
            let [j, k, l] = self.cubic.keys[i].map(|x| x as usize);
            let c = &self.cubic.values[i];
            let ujc = dot(&u[j], c);
            let dkl = dot(&v[k], &u[l]) + dot(&u[k], &v[l]);
            let djc = dot(&v[j], c);
            add_on(j, *c, dkl);
            add_on(k, u[l], djc);
            add_on(k, v[l], ujc);
            add_on(l, u[k], djc);
            add_on(l, v[k], ujc);
        }
        for i in self.terms(1, part) {
            let [a, b, c, e] = self.quartic.keys[i].map(|x| x as usize);
            let d = self.quartic.values[i];
            let (s1, s2) = (d * dot(&u[a], &u[b]), d * dot(&u[c], &u[e]));
            let ds1 = d * (dot(&v[a], &u[b]) + dot(&u[a], &v[b]));
            let ds2 = d * (dot(&v[c], &u[e]) + dot(&u[c], &v[e]));
            add_on(a, u[b], ds2);
            add_on(a, v[b], s2);
            add_on(b, u[a], ds2);
            add_on(b, v[a], s2);
            add_on(c, u[e], ds1);
            add_on(c, v[e], s1);
            add_on(e, u[c], ds1);
            add_on(e, v[c], s1);
        }
    }

    /// Turns adaptive non-linearity (paper 2 §6) on: a vertex becomes non-linear when its
    /// displacement exceeds `threshold` (m) and linear again below `(1 − hysteresis)·threshold`,
    /// so vertices near the threshold do not flicker. A tetrahedron with a non-linear vertex is
    /// St Venant-Kirchhoff, the others linear: its cubic and quartic terms are added to the
    /// tables when it turns non-linear and subtracted when it turns back (the removal mechanism of
    /// eq. 10), so the forces always derive from the energy of the current mix, which is bounded
    /// below. All start linear; call [`TensorMassForceField::update_adaptive`] every step.
    pub fn enable_adaptive(&mut self, model: &TetModel, threshold: f64, hysteresis: f64) {
        let mut vertex_tets = vec![Vec::new(); self.vertex_b.len()];
        for (t, tet) in model.tets.iter().enumerate() {
            for &v in tet {
                vertex_tets[v as usize].push(t as u32);
            }
        }
        self.cubic.clear();
        self.quartic.clear();
        self.adaptive = Some(AdaptiveState {
            threshold,
            hysteresis: hysteresis.clamp(0.0, 1.0),
            flags: vec![false; self.vertex_b.len()],
            nonlinear: 0,
            vertex_tets,
            tet_count: vec![0; model.tets.len()],
            changed: Vec::new(),
            active: [Vec::new(), Vec::new()],
        });
    }

    /// Updates which vertices (and so which live tetrahedra of `topo`) are non-linear from
    /// positions `x`, and the tables with them; returns how many vertices are non-linear.
    ///
    pub fn update_adaptive(&mut self, model: &TetModel, topo: &TetTopology, x: &[Vec3]) -> usize {
        let Some(state) = self.adaptive.as_mut() else {
            return self.nonlinear_count();
        };
        let up = state.threshold * state.threshold;
        let down = (state.threshold * (1.0 - state.hysteresis)).powi(2);
        for (v, (p, r)) in x.iter().zip(&model.rest).enumerate() {
            let d2 = (0..3).map(|k| (p[k] - r[k]).powi(2)).sum::<f64>();
            let on = if d2 > up {
                true
            } else if d2 < down {
                false
            } else {
                continue;
            };
            if on != state.flags[v] {
                state.flags[v] = on;
                state.nonlinear = if on { state.nonlinear + 1 } else { state.nonlinear - 1 };
                for &t in &state.vertex_tets[v] {
                    let c = &mut state.tet_count[t as usize];
                    let was = *c > 0;
                    *c = if on { *c + 1 } else { *c - 1 };
                    if was != (*c > 0) {
                        state.changed.push(t);
                    }
                }
            }
        }
        let count = state.nonlinear;
        if state.changed.is_empty() {
            return count;
        }
        let mut changed = std::mem::take(&mut state.changed);
        changed.sort_unstable();
        changed.dedup();
        let switch_on: Vec<(u32, bool)> =
            changed.iter().map(|&t| (t, state.tet_count[t as usize] > 0)).collect();
        for (t, on) in switch_on {
            if topo.is_alive(t as usize) {
                self.switch_tet(model, topo, t as usize, on);
            }
        }
        self.refresh_active();
        count
    }

    /// Adaptive: which vertices are non-linear now (`None` without adaptive non-linearity).
    #[must_use]
    pub fn nonlinear_vertices(&self) -> Option<&[bool]> {
        self.adaptive.as_ref().map(|a| a.flags.as_slice())
    }

    /// Adaptive: the cubic and quartic tables built again from the non-linear vertices alone,
    /// the live tetrahedra of `topo` added in index order. The tables are sums kept as vertices
    /// switch, so their bits depend on the order of every switch since the start; after this
    /// they depend only on which vertices are non-linear, which is what a state snapshot keeps
    /// (see `incise_sim`'s keyframes). No-op without adaptive non-linearity.
    pub fn rebuild_adaptive_tables(&mut self, model: &TetModel, topo: &TetTopology) {
        let Some(state) = self.adaptive.as_ref() else { return };
        let on: Vec<usize> = (0..state.tet_count.len())
            .filter(|&t| state.tet_count[t] > 0 && topo.is_alive(t))
            .collect();
        self.cubic.clear();
        self.quartic.clear();
        for t in on {
            self.switch_tet(model, topo, t, true);
        }
        self.refresh_active();
    }

    /// Adaptive: sets which vertices are non-linear (one flag per vertex) and builds the tables
    /// for them ([`Self::rebuild_adaptive_tables`]).
    ///
    /// # Errors
    /// Without adaptive non-linearity, or with a flag count other than the vertex count.
    pub fn set_nonlinear_vertices(
        &mut self,
        model: &TetModel,
        topo: &TetTopology,
        flags: &[bool],
    ) -> Result<(), String> {
        let Some(state) = self.adaptive.as_mut() else {
            return Err("the field has no adaptive non-linearity".into());
        };
        if flags.len() != state.flags.len() {
            return Err(format!(
                "{} non-linear flags for {} vertices",
                flags.len(),
                state.flags.len()
            ));
        }
        state.flags = flags.to_vec();
        state.nonlinear = flags.iter().filter(|&&f| f).count();
        state.tet_count.fill(0);
        for (v, tets) in state.vertex_tets.iter().enumerate() {
            if flags[v] {
                for &t in tets {
                    state.tet_count[t as usize] += 1;
                }
            }
        }
        state.changed.clear();
        self.rebuild_adaptive_tables(model, topo);
        Ok(())
    }

    /// Adds (`on`) or subtracts tetrahedron `t`'s cubic and quartic terms.
    fn switch_tet(&mut self, model: &TetModel, topo: &TetTopology, t: usize, on: bool) {
        let terms = tet_terms(model, topo, t, Elasticity::StVenantKirchhoff);
        for (key, c) in &terms.cubic {
            if on {
                self.cubic.add(key, *c, |a, b| (0..3).for_each(|r| a[r] += b[r]));
            } else {
                self.cubic.remove(key, *c, |a, b| (0..3).for_each(|r| a[r] -= b[r]));
            }
        }
        for (key, d) in &terms.quartic {
            if on {
                self.quartic.add(key, *d, |a, b| *a += b);
            } else {
                self.quartic.remove(key, *d, |a, b| *a -= b);
            }
        }
    }

    /// Vertices currently non-linear (all for SVK without adaptivity, none for linear).
    #[must_use]
    pub fn nonlinear_count(&self) -> usize {
        match &self.adaptive {
            Some(state) => state.nonlinear,
            None if self.kind == Elasticity::Linear => 0,
            None => self.vertex_b.len(),
        }
    }

    /// `out += K₀ v`: the rest (linear) stiffness, from the vertex and edge tensors alone.
    pub fn add_rest_stiffness_times(&self, v: &[Vec3], out: &mut [Vec3]) {
        for (n, b) in self.vertex_b.iter().enumerate() {
            let kv = mul_vec(b, &v[n]);
            for k in 0..3 {
                out[n][k] += 2.0 * kv[k];
            }
        }
        for (&[lo, hi], m) in self.edge_vertices.iter().zip(&self.edge_b) {
            let (lo, hi) = (lo as usize, hi as usize);
            let (a, b) = (mul_vec(m, &v[hi]), mul_transpose_vec(m, &v[lo]));
            for k in 0..3 {
                out[lo][k] += a[k];
                out[hi][k] += b[k];
            }
        }
    }

    /// Elastic energy at positions `x` (J), from the stored terms.
    #[must_use]
    pub fn energy(&self, model: &TetModel, x: &[Vec3]) -> f64 {
        let u = displacements(model, x);
        let mut w = 0.0;
        for (n, b) in self.vertex_b.iter().enumerate() {
            w += dot(&u[n], &mul_vec(b, &u[n]));
        }
        for (&[lo, hi], m) in self.edge_vertices.iter().zip(&self.edge_b) {
            w += dot(&u[lo as usize], &mul_vec(m, &u[hi as usize]));
        }
        for part in 0..PARTS {
            for i in self.terms(0, part) {
                let [j, k, l] = self.cubic.keys[i].map(|x| x as usize);
                w += dot(&u[j], &self.cubic.values[i]) * dot(&u[k], &u[l]);
            }
            for i in self.terms(1, part) {
                let [a, b, c, e] = self.quartic.keys[i].map(|x| x as usize);
                w += self.quartic.values[i] * dot(&u[a], &u[b]) * dot(&u[c], &u[e]);
            }
        }
        w
    }
}
