"""Newton (semi-implicit Euler, Warp on the CPU) on the hanging block of docs/benchmarks.md.

The companion of bench_mujoco.py beside it, on the same scenes (scenes.py beside it: the same
grid split into 6 tetrahedra per hexahedron, the top face held, gravity and the 0.5 N corner
pull). Prints one row per scene in bench_mujoco.py's layout: steps/s at dt = 1 ms (median, min,
max of 5 runs), stability at 1 ms and 10 ms, and the pulled corner's displacement after 2 s.

    python3 -m venv ~/.cache/newton-venv && ~/.cache/newton-venv/bin/pip install newton==1.8.0
    ~/.cache/newton-venv/bin/python deploy/peers/bench_newton.py S1 S2 S3 [--scenes-dir DIR]

Newton's tetrahedra are Neo-Hookean (Lamé parameters from E and nu); its stiffness damping is set
to MuJoCo's 1e-3 s times the Lamé parameters.
"""
import argparse
import os
import sys
import time

import numpy as np

REPS = 5
STAB_T = 2.0
STAB_WALL = 60.0
DAMPING = 1e-3


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=["S1", "S2", "S3"])
    ap.add_argument("--scenes-dir", default=os.path.dirname(os.path.abspath(__file__)),
                    help="folder holding scenes.py (default: this script's folder)")
    args = ap.parse_args()
    sys.path.insert(0, os.path.abspath(args.scenes_dir))
    import scenes as S  # noqa: E402
    import warp as wp  # noqa: E402
    import newton  # noqa: E402

    wp.config.quiet = True
    wp.init()
    wp.set_device("cpu")

    class Block:
        def __init__(self, cells, dt):
            pts = S.grid_nodes(cells)
            tets = S.grid_tets(cells)
            mu, lam = S.lame()
            b = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=(0.0, 0.0, -S.G))
            b.add_soft_mesh(pos=(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0,
                            vel=(0.0, 0.0, 0.0), vertices=[tuple(p) for p in pts],
                            indices=tets.ravel().tolist(), density=S.RHO, k_mu=mu,
                            k_lambda=lam, k_damp=DAMPING, particle_radius=1e-4,
                            add_surface_mesh_edges=False)
            for i in np.nonzero(S.fixed_mask(pts))[0]:
                b.particle_mass[int(i)] = 0.0
            self.model = b.finalize(device="cpu")
            self.model.particle_grid = None
            self.solver = newton.solvers.SolverSemiImplicit(self.model, enable_tri_contact=False)
            self.s0, self.s1 = self.model.state(), self.model.state()
            f = np.zeros((len(pts), 3), dtype=np.float32)
            pn = S.pull_nodes(pts)
            f[pn] = S.F_PULL * S.F_DIR / len(pn)
            self.f_ext = wp.array(f, dtype=wp.vec3, device="cpu")
            self.p0 = pts
            self.corner = S.corner_index(pts)
            self.dt = dt
            self.ntet, self.nvert = len(tets), len(pts)

        def step(self):
            wp.copy(self.s0.particle_f, self.f_ext)
            self.solver.step(self.s0, self.s1, None, None, self.dt)
            self.s0, self.s1 = self.s1, self.s0

        def corner_disp(self):
            q = self.s0.particle_q.numpy()
            return float(np.linalg.norm(q[self.corner] - self.p0[self.corner]))

    def stability(cells, dt):
        blk = Block(cells, dt)
        n = int(round(STAB_T / dt))
        hist = []
        t0 = time.perf_counter()
        for i in range(n):
            if time.perf_counter() - t0 > STAB_WALL:
                break
            blk.step()
            if i % max(1, n // 100) == 0:
                hist.append(blk.corner_disp())
                if not np.isfinite(hist[-1]) or hist[-1] > 10:
                    break
        hist.append(blk.corner_disp())
        return S.stable_verdict(hist), hist[-1]

    la0 = S.load_avg()
    rows = []
    for name in args.scenes:
        cells = S.SCENES[name]
        blk = Block(cells, 1e-3)
        steps = S.pick_steps(blk.step, target_s=2.0)
        rates = S.time_runs(blk.step, steps, REPS, warmup_steps=10)
        st1, u1 = stability(cells, 1e-3)
        st10, u10 = stability(cells, 1e-2)
        rows.append((name, blk.ntet, blk.nvert, steps, rates, st1, u1, st10, u10))
    la1 = S.load_avg()
    print(f"# Newton {newton.__version__} (Warp {wp.__version__}, CPU) soft mesh, semi-implicit "
          f"Euler; loadavg before {la0[0]:.2f}, after {la1[0]:.2f}")
    print("(rows time dt = 1 ms; stability columns are per scene)")
    print(f"{'integrator':10s} {'scene':5s} {'tets':>6s} {'nodes':>6s} {'steps/run':>9s} "
          f"{'median':>9s} {'min':>9s} {'max':>9s}  {'dt=1ms':25s} {'|u_c|@2s':>9s}  "
          f"{'dt=10ms':25s} {'|u_c|@2s':>9s}")
    for name, ntet, nvert, steps, rates, st1, u1, st10, u10 in rows:
        print(f"{'semi-impl':10s} {name:5s} {ntet:6d} {nvert:6d} {steps:9d} {S.fmt_rates(rates)}"
              f"  {st1:25s} {u1:9.4f}  {st10:25s} {u10:9.4f}")


if __name__ == "__main__":
    main()
