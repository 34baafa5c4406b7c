//! The tetrahedral model's rest data (P1 shape vectors, volumes, Lamé coefficients, lumped
//! masses) and the conventional element-by-element forces and energy of linear and St
//! Venant-Kirchhoff elasticity, the reference the tensor-mass storage is checked against.
//!
//! Paper 2 §2.1: in tetrahedron `T` the displacement is `U(X) = Σⱼ Uⱼ Λⱼ(X)` with
//! `∇Λⱼ = αⱼ` (the shape vectors). With `∇U = Σⱼ Uⱼ ⊗ αⱼ`:
//! - linear (eq. 1–2): `E_l = ½(∇U + ∇Uᵀ)`, `W = V₀ (λ/2 (tr E_l)² + μ tr E_l²)`;
//! - St Venant-Kirchhoff (eq. 5): `E = ½(∇U + ∇Uᵀ + ∇Uᵀ∇U)`, the same `W` with `E`. The force on
//!   vertex `j` is `−V₀ F S αⱼ`, `F = I + ∇U`, `S = λ tr(E) I + 2μE` (second Piola-Kirchhoff).

use incise_math::Vec3;
use incise_math::mat3::{Mat3, det, mul_vec};
use incise_mesh::{TetMesh, signed_volume};

/// Lamé coefficients (Pa).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lame {
    /// First Lamé coefficient λ.
    pub lambda: f64,
    /// Shear modulus μ.
    pub mu: f64,
}

impl Lame {
    /// From Young's modulus `e` (Pa) and Poisson ratio `nu`.
    #[must_use]
    pub fn from_young_poisson(e: f64, nu: f64) -> Self {
        Self { lambda: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), mu: e / (2.0 * (1.0 + nu)) }
    }
}

/// Which strain measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Elasticity {
    /// Linearised strain (not invariant under rotation: paper 2 §2.2).
    Linear,
    /// Green-St Venant strain.
    StVenantKirchhoff,
}

/// A tissue for a region: Lamé coefficients, density (kg/m³) and an optional fibre direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TetMaterial {
    /// Lamé coefficients (in the plane of isotropy when there is a fibre).
    pub lame: Lame,
    /// Density (kg/m³).
    pub density: f64,
    /// Transverse isotropy: stiffer (or softer) along a fibre direction.
    pub fibre: Option<Fibre>,
}

impl TetMaterial {
    /// An isotropic tissue.
    #[must_use]
    pub fn isotropic(lame: Lame, density: f64) -> Self {
        Self { lame, density, fibre: None }
    }
}

/// A fibre direction `a₀` and the Lamé coefficients `λᴸ, μᴸ` along it (paper 2 §3: the energy gains
/// `((λᴸ − λ)/2 + μᴸ − μ) (a₀ᵀ E a₀)²`, penalising stretch along the fibre).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fibre {
    /// Fibre direction (normalised when the model is built).
    pub direction: Vec3,
    /// Lamé coefficients along the fibre.
    pub lame_along: Lame,
}

impl Fibre {
    /// The unit direction and the coefficient `κ = (λᴸ − λ)/2 + μᴸ − μ` of `(a₀ᵀ E a₀)²`.
    #[must_use]
    pub fn term(&self, lame: Lame) -> (Vec3, f64) {
        let d = self.direction;
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let unit = if n > 0.0 { d.map(|x| x / n) } else { [0.0, 0.0, 1.0] };
        (unit, 0.5 * (self.lame_along.lambda - lame.lambda) + self.lame_along.mu - lame.mu)
    }
}

/// Rest data of every tetrahedron.
#[derive(Clone, Debug)]
pub struct TetModel {
    /// Rest positions (m).
    pub rest: Vec<Vec3>,
    /// Tetrahedra (vertex indices).
    pub tets: Vec<[u32; 4]>,
    /// Shape vectors `αⱼ = ∇Λⱼ` per tetrahedron (1/m).
    pub shape: Vec<[Vec3; 4]>,
    /// Rest volume per tetrahedron (m³).
    pub volume: Vec<f64>,
    /// Lamé coefficients per tetrahedron.
    pub lame: Vec<Lame>,
    /// Lumped mass per vertex (kg): a quarter of each tetrahedron's mass.
    pub lumped_mass: Vec<f64>,
    /// Per tetrahedron, its unit fibre direction `a₀` and coefficient `κ` (see [`Fibre::term`]);
    /// set per region by the material, and may be overwritten per tetrahedron before the force
    /// field is built.
    pub fibre: Vec<Option<(Vec3, f64)>>,
}

/// `∇Λⱼ` of the tetrahedron `p`: rows of the inverse edge matrix, `α₀ = −α₁ − α₂ − α₃`.
#[must_use]
pub fn shape_vectors(p: &[Vec3; 4]) -> [Vec3; 4] {
    let d: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| p[c + 1][r] - p[0][r]));
    let inv_det = 1.0 / det(&d);
    // Rows of D⁻¹ = cofactor columns / det.
    let col = |i: usize| -> Vec3 { std::array::from_fn(|r| d[r][i]) };
    let (c0, c1, c2) = (col(0), col(1), col(2));
    let cross = incise_math::mat3::cross;
    let a1 = cross(&c1, &c2).map(|x| x * inv_det);
    let a2 = cross(&c2, &c0).map(|x| x * inv_det);
    let a3 = cross(&c0, &c1).map(|x| x * inv_det);
    let a0 = std::array::from_fn(|k| -a1[k] - a2[k] - a3[k]);
    [a0, a1, a2, a3]
}

impl TetModel {
    /// The model of `mesh` with `material(region)` per tetrahedron.
    pub fn new(mesh: &TetMesh, material: impl Fn(u32) -> TetMaterial) -> Self {
        let mut lumped_mass = vec![0.0; mesh.vertices().len()];
        let mut shape = Vec::with_capacity(mesh.tets().len());
        let mut volume = Vec::with_capacity(mesh.tets().len());
        let mut lame = Vec::with_capacity(mesh.tets().len());
        let mut fibre = Vec::with_capacity(mesh.tets().len());
        for (t, nodes) in mesh.tets().iter().enumerate() {
            let p = mesh.tet_positions(t);
            let v = signed_volume(&p);
            let m = material(mesh.regions()[t]);
            for &n in nodes {
                lumped_mass[n as usize] += 0.25 * m.density * v;
            }
            shape.push(shape_vectors(&p));
            volume.push(v);
            lame.push(m.lame);
            fibre.push(m.fibre.map(|f| f.term(m.lame)));
        }
        Self {
            rest: mesh.vertices().to_vec(),
            tets: mesh.tets().to_vec(),
            shape,
            volume,
            lame,
            lumped_mass,
            fibre,
        }
    }

    /// Vertices.
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.rest.len()
    }

    /// `∇U` of tetrahedron `t` at positions `x`.
    #[must_use]
    pub fn displacement_gradient(&self, t: usize, x: &[Vec3]) -> Mat3 {
        let mut g = [[0.0; 3]; 3];
        for (j, &n) in self.tets[t].iter().enumerate() {
            let u: Vec3 = std::array::from_fn(|k| x[n as usize][k] - self.rest[n as usize][k]);
            let a = &self.shape[t][j];
            for r in 0..3 {
                for c in 0..3 {
                    g[r][c] += u[r] * a[c];
                }
            }
        }
        g
    }

    /// Strain of tetrahedron `t`: `E_l` or the Green-St Venant `E`.
    fn strain(&self, t: usize, x: &[Vec3], kind: Elasticity) -> (Mat3, Mat3) {
        let g = self.displacement_gradient(t, x);
        let mut e: Mat3 =
            std::array::from_fn(|r| std::array::from_fn(|c| 0.5 * (g[r][c] + g[c][r])));
        if kind == Elasticity::StVenantKirchhoff {
            for r in 0..3 {
                for c in 0..3 {
                    e[r][c] += 0.5 * (0..3).map(|k| g[k][r] * g[k][c]).sum::<f64>();
                }
            }
        }
        (g, e)
    }

    /// Elastic energy of tetrahedron `t` (J).
    #[must_use]
    pub fn element_energy(&self, t: usize, x: &[Vec3], kind: Elasticity) -> f64 {
        let (_, e) = self.strain(t, x, kind);
        let Lame { lambda, mu } = self.lame[t];
        let tr = e[0][0] + e[1][1] + e[2][2];
        let tr2: f64 =
            (0..3).flat_map(|r| (0..3).map(move |c| (r, c))).map(|(r, c)| e[r][c] * e[c][r]).sum();
        let along = self.fibre[t].map_or(0.0, |(a, kappa)| {
            let ea = fibre_strain(&e, &a);
            kappa * ea * ea
        });
        self.volume[t] * (0.5 * lambda * tr * tr + mu * tr2 + along)
    }

    /// Elastic forces of tetrahedron `t` on its 4 vertices (N).
    #[must_use]
    pub fn element_forces(&self, t: usize, x: &[Vec3], kind: Elasticity) -> [Vec3; 4] {
        let (g, e) = self.strain(t, x, kind);
        let Lame { lambda, mu } = self.lame[t];
        let tr = e[0][0] + e[1][1] + e[2][2];
        let mut s: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| 2.0 * mu * e[r][c]));
        for k in 0..3 {
            s[k][k] += lambda * tr;
        }
        // ∂/∂E of κ (a₀ᵀEa₀)² = 2κ (a₀ᵀEa₀) a₀ ⊗ a₀.
        if let Some((a, kappa)) = self.fibre[t] {
            let w = 2.0 * kappa * fibre_strain(&e, &a);
            for r in 0..3 {
                for c in 0..3 {
                    s[r][c] += w * a[r] * a[c];
                }
            }
        }
        // First Piola-Kirchhoff stress: P = F S (SVK), σ (linear).
        let p = match kind {
            Elasticity::Linear => s,
            Elasticity::StVenantKirchhoff => {
                let f: Mat3 = std::array::from_fn(|r| {
                    std::array::from_fn(|c| g[r][c] + if r == c { 1.0 } else { 0.0 })
                });
                incise_math::mat3::mul(&f, &s)
            }
        };
        let v = self.volume[t];
        std::array::from_fn(|j| mul_vec(&p, &self.shape[t][j]).map(|c| -v * c))
    }

    /// `f += Σ forces` over the tetrahedra `live(t)` accepts, in tetrahedron order.
    pub fn add_forces(
        &self,
        live: impl Fn(usize) -> bool,
        x: &[Vec3],
        kind: Elasticity,
        f: &mut [Vec3],
    ) {
        for t in (0..self.tets.len()).filter(|&t| live(t)) {
            let ft = self.element_forces(t, x, kind);
            for (j, &n) in self.tets[t].iter().enumerate() {
                for k in 0..3 {
                    f[n as usize][k] += ft[j][k];
                }
            }
        }
    }

    /// Total elastic energy over the tetrahedra `live(t)` accepts (J).
    #[must_use]
    pub fn energy(&self, live: impl Fn(usize) -> bool, x: &[Vec3], kind: Elasticity) -> f64 {
        (0..self.tets.len()).filter(|&t| live(t)).map(|t| self.element_energy(t, x, kind)).sum()
    }

    /// Current volume of tetrahedron `t` at positions `x` (m³).
    #[must_use]
    pub fn current_volume(&self, t: usize, x: &[Vec3]) -> f64 {
        signed_volume(&self.tets[t].map(|n| x[n as usize]))
    }
}

/// `a₀ᵀ E a₀`.
fn fibre_strain(e: &Mat3, a: &Vec3) -> f64 {
    (0..3).map(|r| a[r] * (0..3).map(|c| e[r][c] * a[c]).sum::<f64>()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_vectors_are_barycentric_gradients() {
        let p = [[0.1, 0.0, 0.0], [1.0, 0.2, 0.0], [0.0, 1.1, 0.3], [0.2, 0.1, 0.9]];
        let a = shape_vectors(&p);
        // Λⱼ(pᵢ) − Λⱼ(p₀) = αⱼ · (pᵢ − p₀) = δᵢⱼ − δ₀ⱼ.
        for i in 1..4 {
            for j in 0..4 {
                let d: f64 = (0..3).map(|k| a[j][k] * (p[i][k] - p[0][k])).sum();
                let want = f64::from(u8::from(i == j)) - f64::from(u8::from(j == 0));
                assert!((d - want).abs() < 1e-14, "{i} {j} {d}");
            }
        }
    }
}
