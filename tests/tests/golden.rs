//! Golden state hashes: the state after a fixed number of steps of committed scenes, pinned bit
//! for bit. Any change to the numbers a step produces (an operation reordered, a tolerance
//! moved, a kernel rewritten) fails here, so such a change is always a deliberate commit that says
//! why the hashes moved and regenerates them (`GOLDEN_PRINT=1 cargo test --release -p incise_tests
//! --test golden -- --nocapture` prints the new values).
//!
//! The hashes hold on any x86-64 machine: the element kernels pick AVX2 at run time
//! and fall back to code that gives the same bits, and the sums over threads are formed in a fixed
//! order whatever the thread count.

use incise_sim::{Simulation, StepInputs};
use incise_tests::scene;

/// Loads a committed scene and steps it `steps` times with no inputs; returns the last frame's
/// state hash.
fn hash_after(name: &str, steps: usize) -> u64 {
    let path = scene(name);
    let scene = incise_scene::read_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut sim = Simulation::new(&scene.config, &scene.geometry, &path.display().to_string())
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut hash = 0;
    for _ in 0..steps {
        hash =
            sim.step(&StepInputs::default()).unwrap_or_else(|e| panic!("{name}: {e}")).state_hash;
    }
    hash
}

fn check(name: &str, steps: usize, expected: u64) {
    let got = hash_after(name, steps);
    if std::env::var_os("GOLDEN_PRINT").is_some() {
        println!("{name} after {steps} steps: {got:#018x}");
    }
    assert_eq!(
        got, expected,
        "{name}: the state after {steps} steps changed ({got:#018x}, pinned {expected:#018x}); if \
         the change is intended, say why in the commit and pin the new hash"
    );
}

#[test]
fn b1_after_200_implicit_steps() {
    check("b1.toml", 200, 0xa57d_c789_10dd_b5a3);
}

#[test]
fn liver_13k_after_100_implicit_steps() {
    check("liver_13k.toml", 100, 0xdb56_e8db_9a0d_0573);
}

#[test]
fn tensor_mass_liver_after_100_explicit_steps() {
    check("liver_tensor_mass.toml", 100, 0x2119_e8d7_29f5_7112);
}

#[test]
fn b3_after_50_implicit_steps_with_the_lockstep_solver() {
    check("b3.toml", 50, 0x6c68_7810_d3b6_a4c1);
}

#[test]
fn cantilever_after_one_static_newton_solve() {
    check("c_20x2x2.toml", 1, 0x525e_34ea_95fa_4cf5);
}
