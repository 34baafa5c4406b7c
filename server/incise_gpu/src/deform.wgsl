// The embedded surface's vertices as weighted sums of node positions (paper 1 §3: a vertex moves
// with the element that owns its material). CPU twin: incise_surface::SurfaceMapping::deformed.
// `embedded` comes from embedded.wgsl, prepended.

struct Params {
    vertex_count: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// Per vertex slot: 8 node ids, then 8 weights (f32 bits); a zero weight is no node.
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> nodes: array<f32>;
@group(0) @binding(2) var<storage, read> embeddings: array<u32>;
@group(0) @binding(3) var<storage, read_write> vertices: array<f32>;

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) id: vec3<u32>) {
    let v = id.x;
    if v >= params.vertex_count {
        return;
    }
    let p = embedded(v);
    vertices[3u * v] = p.x;
    vertices[3u * v + 1u] = p.y;
    vertices[3u * v + 2u] = p.z;
}
