// Layered depth images and their overlap intervals (Faure et al. 2008; paper 1 §3, Fig. 10).
// CPU twin: incise_tool::volume_contact (ldi.rs rasterises, intersection.rs walks the rays).
//
// `raster`: one invocation per triangle slot (its three vertex slots and its surface group, or
// none for a free slot); a slot of the first group is rasterised for side A, of the second for
// side B, any other is skipped. Every pixel centre inside its
// projection (with the CPU's tie rule on shared edges, so a closed surface is crossed once where
// its triangles meet) gets a fragment: depth along the view's axis, triangle, whether the ray
// enters, barycentric weights. A pixel keeps at most `capacity` fragments per surface; more set
// the overflow flag and the caller runs the CPU's pass instead.
//
// `intervals`: one invocation per pixel; its fragments sorted as the CPU sorts them (depth, then
// entering first, then triangle); the depth intervals inside each surface (winding ≥ 1), or
// inside two layers of the one surface (winding ≥ 2); for two surfaces, where their intervals
// overlap. Each overlap interval is appended with the crossings that bound it.

struct View {
    origin: vec2<f32>,
    pixel: vec2<f32>,
    size: vec2<u32>,
    axis: u32,
    layers: u32,
    slots: u32,
    group_a: u32,
    group_b: u32,
    capacity: u32,
    max_intervals: u32,
    pair: u32,
    // The region's extent along the rays: a surface against itself counts only what lies
    // inside it (an interval reaching past is cut there, its cut end weighing nothing).
    depth_lo: f32,
    depth_hi: f32,
}

const CAP: u32 = 16u;
// Words per fragment: depth, triangle (bit 31: entering), three weights.
const FRAGMENT: u32 = 5u;
// Words per interval: pixel, flags (bit 0: start on B, bit 1: end on B, bits 2-3: axis), two
// depths, two triangles, three weights for each bound.
const INTERVAL: u32 = 12u;

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> vertices: array<f32>;
// Per triangle slot: three vertex slots, then the group (0xffffffff: a free slot).
@group(0) @binding(2) var<storage, read> triangles: array<u32>;
@group(0) @binding(4) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> fragments: array<u32>;
@group(0) @binding(6) var<storage, read_write> intervals: array<u32>;
@group(0) @binding(7) var<storage, read_write> status: array<atomic<u32>>;

fn position(i: u32) -> vec3<f32> {
    return vec3<f32>(vertices[3u * i], vertices[3u * i + 1u], vertices[3u * i + 2u]);
}

fn project(p: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(p[(view.axis + 1u) % 3u], p[(view.axis + 2u) % 3u]);
}

// The edge function of from → to at x (positive on its left), as (p − x) × (q − x) with p and q
// the ends in vertex-index order whichever way the edge runs: two triangles sharing the edge get
// values of exactly opposite sign, and so do two edges whose ends project onto the same points
// (a voxel surface's vertical walls seen from above). The CPU twin decides these signs exactly;
// here they are rounded (f32), so a ray within rounding of an edge-on wall may still see a
// crossing twice or not at all.
fn edge(fi: u32, fp: vec2<f32>, ti: u32, tp: vec2<f32>, x: vec2<f32>) -> f32 {
    var p = fp;
    var q = tp;
    var s = 1.0;
    if fi > ti {
        p = tp;
        q = fp;
        s = -1.0;
    }
    return s * ((p.x - x.x) * (q.y - x.y) - (p.y - x.y) * (q.x - x.x));
}

// Whether a centre with edge function e lies on the inner side of the edge p → q of a
// counter-clockwise triangle: strictly, or on a "left or top" edge.
fn covers(e: f32, p: vec2<f32>, q: vec2<f32>) -> bool {
    if e != 0.0 {
        return e > 0.0;
    }
    let du = q.x - p.x;
    let dv = q.y - p.y;
    return dv < 0.0 || (dv == 0.0 && du > 0.0);
}

fn first_pixel(lo: f32, k: u32) -> u32 {
    let x = ceil((lo - view.origin[k]) / view.pixel[k] - 0.5);
    if x <= 0.0 {
        return 0u;
    }
    return min(u32(x), view.size[k]);
}

fn end_pixel(hi: f32, k: u32) -> u32 {
    let x = floor((hi - view.origin[k]) / view.pixel[k] - 0.5);
    if x < 0.0 {
        return 0u;
    }
    return min(u32(x) + 1u, view.size[k]);
}

@compute @workgroup_size(64)
fn raster(@builtin(global_invocation_id) id: vec3<u32>) {
    let t = id.x;
    if t >= view.slots {
        return;
    }
    let group = triangles[4u * t + 3u];
    var side = 0u;
    if group == view.group_a {
        side = 0u;
    } else if view.pair == 1u && group == view.group_b {
        side = 1u;
    } else {
        return;
    }
    let tri = vec3<u32>(triangles[4u * t], triangles[4u * t + 1u], triangles[4u * t + 2u]);
    let p0 = position(tri.x);
    let p1 = position(tri.y);
    let p2 = position(tri.z);
    let nz = cross(p1 - p0, p2 - p0)[view.axis];
    // Edge-on (or not finite): its neighbours' crossings close the surface along this ray.
    if !(nz > 0.0 || nz < 0.0) {
        return;
    }
    let q0 = project(p0);
    let q1 = project(p1);
    let q2 = project(p2);
    // Counter-clockwise in the image plane.
    let flip = nz < 0.0;
    let ia = tri.x;
    let qa = q0;
    var ib = tri.y;
    var qb = q1;
    var ic = tri.z;
    var qc = q2;
    if flip {
        ib = tri.z;
        qb = q2;
        ic = tri.y;
        qc = q1;
    }
    let lo = min(min(q0, q1), q2);
    let hi = max(max(q0, q1), q2);
    let depths = vec3<f32>(p0[view.axis], p1[view.axis], p2[view.axis]);
    var flags = t;
    if flip {
        flags = t | 0x80000000u;
    }
    for (var py = first_pixel(lo.y, 1u); py < end_pixel(hi.y, 1u); py++) {
        for (var px = first_pixel(lo.x, 0u); px < end_pixel(hi.x, 0u); px++) {
            let centre = view.origin + (vec2<f32>(f32(px), f32(py)) + 0.5) * view.pixel;
            let ea = edge(ib, qb, ic, qc, centre);
            let eb = edge(ic, qc, ia, qa, centre);
            let ec = edge(ia, qa, ib, qb, centre);
            if !(covers(ea, qb, qc) && covers(eb, qc, qa) && covers(ec, qa, qb)) {
                continue;
            }
            let sum = ea + eb + ec;
            if sum <= 0.0 {
                continue;
            }
            var w = vec3<f32>(ea, eb, ec) / sum;
            if flip {
                w = vec3<f32>(ea, ec, eb) / sum;
            }
            let pixel = px + view.size.x * py;
            let slot = atomicAdd(&counts[2u * pixel + side], 1u);
            if slot >= view.capacity {
                atomicStore(&status[1], 1u);
                continue;
            }
            let base = ((2u * pixel + side) * view.capacity + slot) * FRAGMENT;
            fragments[base] = bitcast<u32>(dot(w, depths));
            fragments[base + 1u] = flags;
            fragments[base + 2u] = bitcast<u32>(w.x);
            fragments[base + 3u] = bitcast<u32>(w.y);
            fragments[base + 4u] = bitcast<u32>(w.z);
        }
    }
}

struct Crossing {
    depth: f32,
    // Triangle, bit 31: entering.
    tri: u32,
    // Where its weights are in `fragments`.
    at: u32,
}

fn entering(c: Crossing) -> bool {
    return (c.tri & 0x80000000u) != 0u;
}

// Whether a sorts before b: depth, then entering first, then triangle.
fn before(a: Crossing, b: Crossing) -> bool {
    if a.depth != b.depth {
        return a.depth < b.depth;
    }
    if entering(a) != entering(b) {
        return entering(a);
    }
    return (a.tri & 0x7fffffffu) < (b.tri & 0x7fffffffu);
}

var<private> crossings: array<array<Crossing, CAP>, 2>;
var<private> counted: array<u32, 2>;
// Each surface's intervals inside it, as indices of their bounding crossings.
var<private> starts: array<array<u32, CAP>, 2>;
var<private> ends: array<array<u32, CAP>, 2>;
var<private> inside_count: array<u32, 2>;

fn load(pixel: u32, side: u32) {
    let n = min(atomicLoad(&counts[2u * pixel + side]), view.capacity);
    counted[side] = n;
    for (var k = 0u; k < n; k++) {
        let base = ((2u * pixel + side) * view.capacity + k) * FRAGMENT;
        let c = Crossing(bitcast<f32>(fragments[base]), fragments[base + 1u], base);
        // Insertion sort: a pixel holds a few crossings.
        var j = k;
        while j > 0u && before(c, crossings[side][j - 1u]) {
            crossings[side][j] = crossings[side][j - 1u];
            j--;
        }
        crossings[side][j] = c;
    }
}

// The intervals of `side`'s ray inside at least `layers` of its surface.
fn walk(side: u32, layers: i32) {
    var winding = 0i;
    var n = 0u;
    var start = 0u;
    var open = false;
    for (var k = 0u; k < counted[side]; k++) {
        let before_ = winding;
        if entering(crossings[side][k]) {
            winding += 1i;
        } else {
            winding -= 1i;
        }
        if before_ < layers && winding >= layers {
            start = k;
            open = true;
        } else if before_ >= layers && winding < layers && open {
            starts[side][n] = start;
            ends[side][n] = k;
            n++;
            open = false;
        }
    }
    inside_count[side] = n;
}

fn emit(pixel: u32, s_side: u32, s: Crossing, e_side: u32, e: Crossing, d0: f32, d1: f32, cut_s: bool, cut_e: bool) {
    let k = atomicAdd(&status[0], 1u);
    if k >= view.max_intervals {
        atomicStore(&status[1], 1u);
        return;
    }
    let base = k * INTERVAL;
    intervals[base] = pixel;
    intervals[base + 1u] = s_side | (e_side << 1u) | (view.axis << 2u);
    intervals[base + 2u] = bitcast<u32>(d0);
    intervals[base + 3u] = bitcast<u32>(d1);
    intervals[base + 4u] = s.tri & 0x7fffffffu;
    intervals[base + 5u] = e.tri & 0x7fffffffu;
    for (var c = 0u; c < 3u; c++) {
        intervals[base + 6u + c] = select(fragments[s.at + 2u + c], 0u, cut_s);
        intervals[base + 9u + c] = select(fragments[e.at + 2u + c], 0u, cut_e);
    }
}

@compute @workgroup_size(64)
fn intervals_of_pixels(@builtin(global_invocation_id) id: vec3<u32>) {
    let pixel = id.x;
    if pixel >= view.size.x * view.size.y {
        return;
    }
    load(pixel, 0u);
    walk(0u, i32(view.layers));
    if view.pair == 0u {
        for (var k = 0u; k < inside_count[0]; k++) {
            let s = crossings[0][starts[0][k]];
            let e = crossings[0][ends[0][k]];
            let d0 = max(s.depth, view.depth_lo);
            let d1 = min(e.depth, view.depth_hi);
            if d1 > d0 {
                emit(pixel, 0u, s, 0u, e, d0, d1, (s.depth < view.depth_lo), (e.depth > view.depth_hi));
            }
        }
        return;
    }
    load(pixel, 1u);
    walk(1u, 1i);
    var i = 0u;
    var j = 0u;
    while i < inside_count[0] && j < inside_count[1] {
        let sa = crossings[0][starts[0][i]];
        let ea = crossings[0][ends[0][i]];
        let sb = crossings[1][starts[1][j]];
        let eb = crossings[1][ends[1][j]];
        var s = sb;
        var s_side = 1u;
        if sa.depth >= sb.depth {
            s = sa;
            s_side = 0u;
        }
        var e = eb;
        var e_side = 1u;
        if ea.depth <= eb.depth {
            e = ea;
            e_side = 0u;
        }
        if e.depth > s.depth {
            emit(pixel, s_side, s, e_side, e, s.depth, e.depth, false, false);
        }
        if ea.depth <= eb.depth {
            i++;
        } else {
            j++;
        }
    }
}
