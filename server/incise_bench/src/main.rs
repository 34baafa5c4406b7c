//! `incise-bench`: the reports that measure incise. Each prints a table a person can read and,
//! with `--json`, ends with one line holding one JSON object for scripts.

mod coexist;
mod frame;
mod grid_report;
mod haptics;
mod latency;
mod ldi;
mod peers;
mod plot;
mod progress;
mod role;
mod speed_error;
mod stroke;
mod tensor_mass;
mod timing;

use clap::{Parser, Subcommand};

/// Benchmarks and reports for incise (release build recommended: `cargo run --release -p incise_bench -- …`).
#[derive(Parser, Debug)]
#[command(name = "incise-bench", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
#[allow(clippy::large_enum_variant, reason = "parsed once at start-up and never moved around")]
enum Command {
    /// Dynamic Branched Grid report: per-level element and node counts, build time, direct vs
    /// recursive condensation, and a 500-voxel cut stroke updated incrementally vs rebuilt.
    Grid(grid_report::GridArgs),
    /// Speed against error on scenes B (hanging block), B2-moving (the block under a travelling
    /// pull), C (cantilever) and the liver, for each model, integrator and dt in {1 ms, 10 ms};
    /// table, CSV, JSON and a log-log PNG.
    SpeedError(speed_error::SpeedErrorArgs),
    /// The liver's accuracy reference: the 13,648-voxel liver at level 0 against the
    /// 109,201-voxel liver at level 0 (static, hanging), compared at the coarse voxels'
    /// centres: centre-of-mass, largest and RMS displacement, and the fields' RMS difference.
    Reference(speed_error::reference::ReferenceArgs),
    /// The branched grid's levels as a multigrid preconditioner against block-Jacobi CG and
    /// sparse Cholesky on the liver's finest levels: the static system and the implicit step's
    /// at 1 and 10 ms, iterations and times, and one operator product's time.
    Multigrid(speed_error::multigrid::MultigridArgs),
    /// Paper 2's Table 1 (volume change of a bent cylinder and a pulled liver for the linear,
    /// St Venant-Kirchhoff and SVK + incompressibility tensor-mass models, and corotational
    /// hexahedra), explicit speed per model, and adaptive non-linearity against full SVK.
    TensorMass(tensor_mass::TensorMassArgs),
    /// A 1 kHz probe thread beside the stepping physics, for physics on 1 and 2 threads with
    /// spinning and sleeping idle workers: the probe's period jitter (p50, p99, max) and the
    /// physics' steps per second.
    Coexist(coexist::CoexistArgs),
    /// The full surgical frame on an organ: a scripted scalpel approaches, presses, cuts a stroke
    /// and retracts, and a second blade separates a piece; per-stage times (median, p99), the
    /// full-frame rate and the cut stroke's grid, condensation and re-mesh time.
    Frame(frame::FrameArgs),
    /// One volume-contact pass (three layered depth images and their rays' overlap intervals)
    /// on the CPU and on a GPU (a software one where there is no other) at several resolutions,
    /// on a scene with a pair of tissues in contact: times, their ratio, and how far the
    /// overlap volumes differ.
    Ldi(ldi::LdiArgs),
    /// Pose → force round trip over zenoh or iceoryx2 between a real server on the liver and a
    /// client in another process sending poses at 1 kHz while it presses and cuts (p50, p99,
    /// p99.9, max), and the haptic thread's period jitter meanwhile; then the same client
    /// against an echo server that answers at once (the transport's floor on this machine).
    /// `--via-router --scenes N`: N servers of their own scene behind one zenoh router, one
    /// client each, all at once.
    Latency(latency::LatencyArgs),
    /// How the tools feel through a real server (the demo scene unless `--scene`), over
    /// iceoryx2 and zenoh: each tool's depth sweep, jab and press-release cycles driven by a
    /// client in another process at 1 kHz; per tool, the proxy's largest penetration (from the
    /// recording replayed bit for bit), the largest force step between two ticks, the energy the
    /// device receives over the cycles, and the haptic tick's cost (p50, p99).
    Haptics(haptics::HapticsArgs),
    /// `haptics`' server process (started by `haptics`).
    #[command(hide = true)]
    HapticsServer(haptics::ServerRole),
    /// `haptics`' client process (started by `haptics`).
    #[command(hide = true)]
    HapticsClient(haptics::ClientRole),
    /// `latency`'s server process (started by `latency`).
    #[command(hide = true)]
    LatencyServer(latency::ServerRole),
    /// `latency`'s client process (started by `latency`).
    #[command(hide = true)]
    LatencyClient(latency::ClientRole),
    /// `latency`'s echo server: answers every pose at once, no physics (started by `latency`).
    #[command(hide = true)]
    LatencyEcho(latency::EchoRole),
    /// `latency --via-router`'s zenoh router (started by `latency`).
    #[command(hide = true)]
    LatencyRouter(latency::RouterRole),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Grid(args) => grid_report::run(&args),
        Command::SpeedError(args) => speed_error::run(&args),
        Command::Reference(args) => speed_error::reference::run(&args),
        Command::Multigrid(args) => speed_error::multigrid::run(&args),
        Command::TensorMass(args) => tensor_mass::run(&args),
        Command::Coexist(args) => coexist::run(&args),
        Command::Frame(args) => frame::run(&args),
        Command::Ldi(args) => ldi::run(&args),
        Command::Haptics(args) => haptics::run(&args),
        Command::HapticsServer(role) => haptics::serve(&role),
        Command::HapticsClient(role) => haptics::client(&role),
        Command::Latency(args) => latency::run(&args),
        Command::LatencyServer(role) => latency::serve(&role),
        Command::LatencyClient(role) => latency::client(&role),
        Command::LatencyEcho(role) => latency::echo(&role),
        Command::LatencyRouter(role) => latency::route(&role),
    }
}
