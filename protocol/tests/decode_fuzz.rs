//! Fuzz-style: arbitrary bytes on the wire never panic a decoder, and whatever decodes converts
//! and checks without panicking.

use incise_protocol::check::check_pose;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_protocol::v1;
use proptest::prelude::*;
use prost::Message;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_bytes_never_panic_any_decoder(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        if let Ok(pose) = v1::ToolPose::decode(bytes.as_slice())
            && let Ok(raw) = RawToolPose::try_from(&pose)
        {
            let _ = check_pose(&raw);
        }
        if let Ok(force) = v1::ToolForce::decode(bytes.as_slice()) {
            let _ = RawToolForce::from(&force);
        }
        let _ = v1::FrameStats::decode(bytes.as_slice());
        let _ = v1::CutEvent::decode(bytes.as_slice());
        let _ = v1::SurfaceMesh::decode(bytes.as_slice());
        let _ = v1::SceneInfo::decode(bytes.as_slice());
    }

    /// A valid pose with some bytes flipped decodes to something or fails cleanly.
    #[test]
    fn damaged_poses_never_panic(flips in proptest::collection::vec((0usize..200, any::<u8>()), 1..6)) {
        let mut bytes = v1::ToolPose::from(&RawToolPose::at(3, [0.01, 0.02, 0.03])).encode_to_vec();
        for (at, byte) in flips {
            let n = bytes.len();
            bytes[at % n] ^= byte;
        }
        if let Ok(pose) = v1::ToolPose::decode(bytes.as_slice())
            && let Ok(raw) = RawToolPose::try_from(&pose)
        {
            let _ = check_pose(&raw);
        }
    }
}

#[test]
fn the_descriptor_set_describes_every_message() {
    let set = prost_types_free_names(incise_protocol::DESCRIPTOR_SET);
    for name in ["ToolPose", "ToolForce", "FrameStats", "CutEvent", "SurfaceMesh", "SceneInfo"] {
        assert!(set.iter().any(|n| n == name), "{name} missing from the descriptor set");
    }
}

/// The message names in an encoded `FileDescriptorSet`, read with prost's wire format alone:
/// `set.file` (1) → `file.message_type` (4) → `message.name` (1).
fn prost_types_free_names(bytes: &[u8]) -> Vec<String> {
    #[derive(Message)]
    struct Set {
        #[prost(message, repeated, tag = "1")]
        file: Vec<File>,
    }
    #[derive(Message)]
    struct File {
        #[prost(message, repeated, tag = "4")]
        message_type: Vec<Msg>,
    }
    #[derive(Message)]
    struct Msg {
        #[prost(string, optional, tag = "1")]
        name: Option<String>,
    }
    Set::decode(bytes)
        .unwrap()
        .file
        .into_iter()
        .flat_map(|f| f.message_type)
        .filter_map(|m| m.name)
        .collect()
}
