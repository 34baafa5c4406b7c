//! Each kernel against its CPU twin, on whatever adapter this machine has (`gpu = "on"`: a
//! software rasteriser, lavapipe, where there is no GPU; CI installs it). The device computes in
//! `f32`, the CPU in `f64`; each tolerance below says where the difference comes from.

use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_gpu::cut_mark::CutMark;
use incise_gpu::deform::Deform;
use incise_gpu::{Gpu, GpuChoice, GpuContact};
use incise_math::Vec3;
use incise_tool::volume_contact::{
    ContactDevice, Overlap, TriangleSurface, overlaps, regions_of, self_overlaps, self_overlaps_in,
};
use incise_tool::{Pose, Primitive, Shape};

fn gpu() -> Gpu {
    Gpu::new(GpuChoice::On).unwrap_or_else(|e| {
        panic!(
            "{e}\nThe GPU tests need an adapter: on Debian, `apt-get install mesa-vulkan-drivers \
             libvulkan1` gives the software one (lavapipe)."
        )
    })
}

/// A small deterministic generator (xorshift).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` embeddings of up to 8 nodes each among `nodes`, weights summing to 1.
fn embeddings(rng: &mut Rng, count: usize, nodes: usize) -> Vec<EmbeddedPoint> {
    (0..count)
        .map(|_| {
            let mut e = EmbeddedPoint { nodes: [0; 8], weights: [0.0; 8] };
            let used = 1 + (rng.next() * 8.0) as usize % 8;
            let mut sum = 0.0;
            for k in 0..used {
                e.nodes[k] = (rng.next() * nodes as f64) as u32 % nodes as u32;
                e.weights[k] = rng.next() + 0.01;
                sum += e.weights[k];
            }
            for w in &mut e.weights[..used] {
                *w /= sum;
            }
            e
        })
        .collect()
}

fn cpu_deform(e: &[EmbeddedPoint], x: &[Vec3]) -> Vec<Vec3> {
    e.iter()
        .map(|e| {
            let mut p = [0.0; 3];
            for k in 0..8 {
                for c in 0..3 {
                    p[c] += e.weights[k] * x[e.nodes[k] as usize][c];
                }
            }
            p
        })
        .collect()
}

#[test]
fn the_surface_deforms_as_on_the_cpu_and_a_cut_sends_only_what_changed() {
    // f32 rounds each of ≤ 8 products and sums to 2⁻²⁴ ≈ 6e-8 of the coordinates' size (0.2 m
    // here), each: 16 roundings bound the difference by 16 × 6e-8 × 0.2 m ≈ 2e-7 m.
    let gpu = gpu();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let nodes: Vec<Vec3> =
        (0..500).map(|_| [0.2 * rng.next(), 0.2 * rng.next() - 0.1, 0.15 * rng.next()]).collect();
    let mut e = embeddings(&mut rng, 3000, nodes.len());
    let mut deform = Deform::new(&gpu);
    assert_eq!(deform.set_embeddings(&gpu, &e, nodes.len()), 3000);
    deform.run(&gpu, &nodes);
    let worst = |got: &[Vec3], want: &[Vec3]| {
        got.iter()
            .zip(want)
            .flat_map(|(g, w)| (0..3).map(move |c| (g[c] - w[c]).abs()))
            .fold(0.0, f64::max)
    };
    let diff = worst(&deform.vertices(&gpu), &cpu_deform(&e, &nodes));
    println!("deform: largest difference {diff:.2e} m over 3000 vertices");
    assert!(diff <= 2e-7, "{diff}");
    // A cut changes a few embeddings: only those go to the device, and the result follows.
    let changed = [7usize, 8, 9, 1500, 2999];
    let fresh = embeddings(&mut rng, changed.len(), nodes.len());
    for (&slot, f) in changed.iter().zip(fresh) {
        e[slot] = f;
    }
    assert_eq!(deform.set_embeddings(&gpu, &e, nodes.len()), changed.len());
    deform.run(&gpu, &nodes);
    assert!(worst(&deform.vertices(&gpu), &cpu_deform(&e, &nodes)) <= 2e-7);
    assert_eq!(deform.set_embeddings(&gpu, &e, nodes.len()), 0, "nothing changed, nothing sent");
}

/// A closed surface owning its data.
struct Mesh {
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

fn icosphere(centre: Vec3, r: f64, levels: usize) -> Mesh {
    let m = incise_mesh::generate::icosphere(centre, r, levels);
    Mesh { positions: m.vertices().to_vec(), triangles: m.triangles().to_vec() }
}

/// Both meshes' vertices in one list, and each one's triangles into it.
fn together(a: &Mesh, b: &Mesh) -> (Vec<Vec3>, Vec<[u32; 3]>, Vec<[u32; 3]>) {
    let shift = a.positions.len() as u32;
    let positions = a.positions.iter().chain(&b.positions).copied().collect();
    let tb = b.triangles.iter().map(|t| t.map(|v| v + shift)).collect();
    (positions, a.triangles.clone(), tb)
}

/// The overlaps the device finds for these vertices (each its own node) and groups.
fn on_device(
    device: &mut GpuContact,
    positions: &[Vec3],
    a: &[[u32; 3]],
    b: Option<&[[u32; 3]]>,
    region: (Vec3, Vec3),
    resolution: usize,
) -> Vec<Overlap> {
    let identity: Vec<EmbeddedPoint> =
        (0..positions.len() as u32).map(EmbeddedPoint::node).collect();
    device.set_embeddings(&identity, positions.len());
    // Group 0's slots, then group 1's, then a free slot (skipped).
    let mut slots: Vec<([u32; 3], Option<u16>)> = a.iter().map(|&t| (t, Some(0))).collect();
    slots.extend(b.unwrap_or(&[]).iter().map(|&t| (t, Some(1))));
    slots.push(([0, 1, 2], None));
    device.set_triangles(&slots);
    device.deform(positions);
    let intervals = device
        .overlap_intervals(0, b.map(|_| 1), region, resolution)
        .expect("the views fit the device");
    regions_of(&intervals, region, resolution)
}

fn overlap_box(a: &TriangleSurface<'_>, b: &TriangleSurface<'_>) -> (Vec3, Vec3) {
    let ((alo, ahi), (blo, bhi)) = (a.bounds().unwrap(), b.bounds().unwrap());
    (std::array::from_fn(|k| alo[k].max(blo[k])), std::array::from_fn(|k| ahi[k].min(bhi[k])))
}

/// Compares two region lists: the same count, each volume by axis within `rel` of the CPU's,
/// and each vertex's gradient within `rel` of the largest gradient component.
fn compare(gpu: &[Overlap], cpu: &[Overlap], rel: f64, what: &str) -> f64 {
    assert_eq!(gpu.len(), cpu.len(), "{what}: regions");
    let mut worst: f64 = 0.0;
    for (g, c) in gpu.iter().zip(cpu) {
        for k in 0..3 {
            let d = (g.volume_by_axis[k] - c.volume_by_axis[k]).abs() / c.volume;
            worst = worst.max(d);
            assert!(
                d <= rel,
                "{what}: axis {k} volume {} against {}",
                g.volume_by_axis[k],
                c.volume_by_axis[k]
            );
        }
        let scale = c
            .gradient_a
            .iter()
            .chain(&c.gradient_b)
            .flat_map(|(_, v)| v.iter().map(|x| x.abs()))
            .fold(0.0, f64::max);
        for (gl, cl) in [(&g.gradient_a, &c.gradient_a), (&g.gradient_b, &c.gradient_b)] {
            let at = |l: &[(u32, Vec3)], v: u32| {
                l.iter().find(|(w, _)| *w == v).map_or([0.0; 3], |(_, d)| *d)
            };
            for &(v, d) in gl.iter().chain(cl.iter()) {
                let (x, y) = (at(gl, v), at(cl, v));
                for k in 0..3 {
                    assert!(
                        (x[k] - y[k]).abs() <= 0.05 * scale,
                        "{what}: vertex {v} axis {k}: {} against {} (of {d:?})",
                        x[k],
                        y[k]
                    );
                }
            }
        }
    }
    worst
}

#[test]
fn the_depth_images_overlap_as_on_the_cpu() {
    // The device's depths and weights are f32 (a relative 6e-8 of the unit-sized scenes) and its
    // coverage tests are f32 too: a pixel centre within ~1e-7 of a silhouette edge may be
    // covered on one side and not the other, moving that pixel's interval (at most its area
    // times the overlap's thickness there, which is near zero at a silhouette). Measured on
    // lavapipe: 2e-8 to 9e-7 of the volume (the grazing overlap, thinnest, the most); allowed
    // 1e-4. A vertex's gradient is a sum over the pixels its
    // triangles cover, and one pixel moved between neighbouring triangles shifts a few percent of
    // one vertex's share: allowed 5 % of the largest component.
    let gpu = gpu();
    let mut device = GpuContact::on(gpu);
    println!("adapter: {}", device.name());
    let cases = [
        ("two spheres", icosphere([0.0; 3], 1.0, 3), icosphere([1.2, 0.1, -0.05], 0.8, 3), 64),
        (
            "a sphere through another",
            icosphere([0.0; 3], 1.0, 2),
            icosphere([0.3, 0.2, 0.1], 0.5, 3),
            48,
        ),
        ("grazing", icosphere([0.0; 3], 1.0, 3), icosphere([1.95, 0.0, 0.0], 1.0, 3), 32),
    ];
    for (what, a, b, resolution) in cases {
        let (positions, ta, tb) = together(&a, &b);
        let sa = TriangleSurface { positions: &positions, triangles: &ta };
        let sb = TriangleSurface { positions: &positions, triangles: &tb };
        let region = overlap_box(&sa, &sb);
        let cpu = overlaps(&sa, &sb, resolution);
        let gpu = on_device(&mut device, &positions, &ta, Some(&tb), region, resolution);
        let worst = compare(&gpu, &cpu, 1e-4, what);
        let volume: f64 = cpu.iter().map(|o| o.volume).sum();
        println!(
            "{what}: {} region(s), volume {volume:.6}, largest relative difference {worst:.1e}",
            cpu.len()
        );
        assert!(volume > 0.0, "{what} overlaps");
    }
    // One surface made of two interpenetrating spheres, against itself.
    let (positions, ta, tb) =
        together(&icosphere([0.0; 3], 1.0, 3), &icosphere([0.7, 0.5, 0.3], 0.8, 3));
    let all: Vec<[u32; 3]> = ta.iter().chain(&tb).copied().collect();
    let s = TriangleSurface { positions: &positions, triangles: &all };
    let cpu = self_overlaps(&s, 48);
    let region = s.bounds().unwrap();
    let gpu = on_device(&mut device, &positions, &all, None, region, 48);
    let worst = compare(&gpu, &cpu, 1e-4, "self");
    println!("self-overlap: volume {:.6}, largest relative difference {worst:.1e}", cpu[0].volume);
    // Only part of it, in a box that cuts through the overlap: the intervals are cut at the
    // box's faces on both.
    let region = ([0.2, -2.0, -2.0], [2.0, 2.0, 0.5]);
    let cpu = self_overlaps_in(&s, region, 48);
    let gpu = on_device(&mut device, &positions, &all, None, region, 48);
    let worst = compare(&gpu, &cpu, 1e-4, "self, in a box");
    println!(
        "self-overlap in a box: volume {:.6}, largest relative difference {worst:.1e}",
        cpu[0].volume
    );
    // Apart: nothing, on both.
    let (positions, ta, tb) =
        together(&icosphere([0.0; 3], 1.0, 2), &icosphere([0.0, 0.0, 2.5], 1.0, 2));
    let region = ([-1.0, -1.0, 1.5], [1.0, 1.0, 1.0]);
    assert!(on_device(&mut device, &positions, &ta, Some(&tb), region, 16).is_empty());
}

#[test]
fn the_cut_marks_are_the_cpus() {
    // A centre is marked when it lies strictly inside the shape. f32 moves a centre by ~2e-8 m
    // (0.1 m coordinates) and the tests by as much: centres within 1e-6 m of the surface may
    // come out either way and are not compared; every other one must agree.
    let gpu = gpu();
    let mut marker = CutMark::new(&gpu);
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let nodes: Vec<Vec3> =
        (0..400).map(|_| [0.1 * rng.next(), 0.1 * rng.next(), 0.1 * rng.next()]).collect();
    let centres = embeddings(&mut rng, 4000, nodes.len());
    let positions = cpu_deform(&centres, &nodes);
    // A unit quaternion: 0.81 + 0.01 + 0.09 + 0.09 = 1.
    let pose = Pose::new([0.05, 0.05, 0.05], [0.9, 0.1, -0.3, 0.3]).unwrap();
    let shapes = [
        Shape::new(Primitive::Sphere { radius: 0.02 }, [0.001, 0.0, 0.0]).unwrap(),
        Shape::new(Primitive::Capsule { radius: 0.01, length: 0.03 }, [0.0; 3]).unwrap(),
        Shape::new(Primitive::Cuboid { half_extents: [0.02, 0.01, 0.015] }, [0.0, 0.002, 0.0])
            .unwrap(),
        Shape::new(
            Primitive::Blade { length: 0.03, height: 0.02, thickness: 0.004 },
            [0.0, 0.0, -0.005],
        )
        .unwrap(),
    ];
    for shape in &shapes {
        let marks = marker.run(&gpu, shape, &pose, &nodes, &centres).expect("a primitive");
        let (mut inside, mut compared) = (0, 0);
        for (p, &m) in positions.iter().zip(&marks) {
            let d = shape.distance(pose.tool_from_grid(*p)).0;
            if d.abs() < 1e-6 {
                continue;
            }
            compared += 1;
            inside += usize::from(m);
            assert_eq!(m, d < 0.0, "{:?}: a centre {d:e} m from the surface", shape.primitive());
        }
        println!("{:?}: {inside} of {compared} centres inside", shape.primitive().unwrap());
        assert!(inside > 0, "the shape holds some centres");
    }
}
