// Which voxels a tool's cutting shape holds: a voxel is cut when its deformed centre (a weighted
// sum of node positions, as a surface vertex is) lies strictly inside the shape, tested in the
// tool's frame. CPU twin: incise_tool::Shape::distance(pose.tool_from_grid(centre)) < 0.

struct Tool {
    // Columns of the tool's rotation (tool frame → grid frame), and its position.
    r0: vec4<f32>,
    r1: vec4<f32>,
    r2: vec4<f32>,
    position: vec4<f32>,
    // The shape's offset in the tool frame.
    offset: vec4<f32>,
    // Sphere: (radius); capsule: (radius, length); box: half extents; blade: (length, height,
    // thickness).
    size: vec4<f32>,
    // 0 sphere, 1 capsule, 2 box, 3 blade.
    kind: u32,
    count: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> tool: Tool;
@group(0) @binding(1) var<storage, read> nodes: array<f32>;
// Per candidate voxel its centre's embedding (`embedded`, from embedded.wgsl, prepended).
@group(0) @binding(2) var<storage, read> embeddings: array<u32>;
@group(0) @binding(3) var<storage, read_write> marks: array<u32>;

fn inside_box(p: vec3<f32>, h: vec3<f32>) -> bool {
    let q = abs(p) - h;
    return max(q.x, max(q.y, q.z)) < 0.0;
}

@compute @workgroup_size(64)
fn cut_mark(@builtin(global_invocation_id) id: vec3<u32>) {
    let v = id.x;
    if v >= tool.count {
        return;
    }
    let c = embedded(v);
    // Into the tool's frame (the rotation's transpose), then the shape's.
    let d = c - tool.position.xyz;
    let p = vec3<f32>(dot(tool.r0.xyz, d), dot(tool.r1.xyz, d), dot(tool.r2.xyz, d)) - tool.offset.xyz;
    var inside = false;
    switch tool.kind {
        case 0u: {
            inside = length(p) < tool.size.x;
        }
        case 1u: {
            inside = length(vec3<f32>(p.x, p.y, p.z - clamp(p.z, 0.0, tool.size.y))) < tool.size.x;
        }
        case 2u: {
            inside = inside_box(p, tool.size.xyz);
        }
        default: {
            let h = tool.size.y;
            inside = inside_box(vec3<f32>(p.x, p.y, p.z - 0.5 * h), 0.5 * vec3<f32>(tool.size.x, tool.size.z, h));
        }
    }
    marks[v] = select(0u, 1u, inside);
}
