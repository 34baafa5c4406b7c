//! Steps paper 2's cylinder with the tensor-mass model for profiling (`perf record`), printing the
//! time per explicit step: `cargo run --release -p incise_fem --example profile_tet -- 6,9 svk 20000`
//! (cells across and along; `linear`, `svk` or `svk-incompressible`).

use incise_fem::FixedNodes;
use incise_fem::forcefield::tet::incompressible::Incompressibility;
use incise_fem::forcefield::tet::{Elasticity, Lame, TensorMassForceField, TetMaterial, TetModel};
use incise_fem::ode::central_difference::CentralDifference;
use incise_mesh::TetTopology;
use incise_mesh::generate::cylinder;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cells: Vec<usize> = args
        .get(1)
        .map_or("6,9", String::as_str)
        .split(',')
        .map(|s| s.parse().expect("cells like 6,9"))
        .collect();
    let scheme = args.get(2).map_or("svk", String::as_str).to_owned();
    let steps: usize = args.get(3).map_or(20_000, |s| s.parse().expect("steps"));
    let mesh = cylinder(0.01, 0.03, cells[0], cells[1]);
    let lame = Lame::from_young_poisson(3_000.0, 0.45);
    let model = TetModel::new(&mesh, |_| TetMaterial::isotropic(lame, 1_000.0));
    let topo = TetTopology::new(&mesh);
    let kind = if scheme == "linear" { Elasticity::Linear } else { Elasticity::StVenantKirchhoff };
    let ff = TensorMassForceField::new(&model, &topo, kind);
    let penalty =
        (scheme == "svk-incompressible").then_some(Incompressibility { kappa: lame.lambda });
    let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-9);
    let mut x = model.rest.clone();
    let stable = incise_fem::ode::central_difference::stable_dt(&model, &ff, &fixed);
    let mut cd = CentralDifference::new(&model, &ff, &fixed, &x, stable, 5.0).expect("stable");
    let gravity: Vec<[f64; 3]> = model.lumped_mass.iter().map(|m| [m * 9.81, 0.0, 0.0]).collect();
    let start = std::time::Instant::now();
    for _ in 0..steps {
        cd.step(&model, &topo, &ff, penalty.as_ref(), &fixed, &gravity, &mut x);
    }
    let s = start.elapsed().as_secs_f64();
    let (v, e, c, q) = ff.term_counts();
    println!(
        "{} tets, {scheme}, dt {stable:.2e} s: {:.1} µs/step, {:.0} steps/s ({v} vertex, {e} edge, {c} cubic, {q} quartic terms)",
        mesh.tets().len(),
        1e6 * s / steps as f64,
        steps as f64 / s
    );
}
