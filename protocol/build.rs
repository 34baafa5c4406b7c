//! Compiles `proto/incise/v1/*.proto` (and the Foxglove schemas recordings use) with protox (no protoc on the machine), generates the
//! Rust types with prost, and keeps the encoded `FileDescriptorSet` for readers that decode
//! without our code (the recorder embeds it).

use protox::prost::Message;
use std::path::PathBuf;

const PROTOS: [&str; 5] = [
    "proto/incise/v1/tool.proto",
    "proto/incise/v1/frame.proto",
    "proto/incise/v1/scene.proto",
    "proto/incise/v1/record.proto",
    "proto/foxglove/scene.proto",
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    for proto in PROTOS {
        println!("cargo:rerun-if-changed={proto}");
    }
    let descriptors = protox::compile(PROTOS, ["proto"])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    // Recordings embed the set once per channel's schema: without the comments (source info),
    // which decoding does not use, it is a quarter of the size. The generated code keeps them
    // as doc comments.
    let mut embedded = descriptors.clone();
    for file in &mut embedded.file {
        file.source_code_info = None;
    }
    std::fs::write(out.join("incise_v1_descriptor_set.bin"), embedded.encode_to_vec())?;
    prost_build::Config::new().compile_fds(descriptors)?;
    Ok(())
}
