// Shared by the kernels that evaluate embedded points (prepended to their source): a point is
// the weighted sum of up to 8 node positions. The kernel declares `nodes` (packed f32 triples)
// and `embeddings` (per point: 8 node ids, then 8 weights as f32 bits; a zero weight is no node).

fn embedded(v: u32) -> vec3<f32> {
    var p = vec3<f32>(0.0, 0.0, 0.0);
    for (var k = 0u; k < 8u; k++) {
        let w = bitcast<f32>(embeddings[16u * v + 8u + k]);
        if w != 0.0 {
            let n = embeddings[16u * v + k];
            p += w * vec3<f32>(nodes[3u * n], nodes[3u * n + 1u], nodes[3u * n + 2u]);
        }
    }
    return p;
}
