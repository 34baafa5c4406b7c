//! Key expressions (zenoh) and service names (iceoryx2): every name the transports use, here
//! and nowhere else.
//!
//! ```text
//! incise/v1/<scene>/tool/<id>/pose     ToolPose, client → server
//! incise/v1/<scene>/tool/<id>/force    ToolForce, server → client
//! incise/v1/<scene>/frame              FrameStats, once per physics frame
//! incise/v1/<scene>/cut                CutEvent, when a tool cuts
//! incise/v1/<scene>/surface            SurfaceMesh, full or delta
//! incise/v1/<scene>/info               SceneInfo, a zenoh queryable (answered on request)
//! incise/v1/<scene>/stats              ServerStats, a zenoh queryable (answered on request)
//! incise/v1/<scene>/tool/poses         iceoryx2 event: a client published poses
//! ```
//!
//! iceoryx2 services carry the same names; a tool's `force` name is also the event service that
//! wakes its client when a force is published. A scene name is what a user typed in a scene file,
//! so it is checked here: letters, digits, `_` and `-` only, which keeps it one chunk of a key
//! expression with no wildcard or separator in it.

use std::fmt;

/// The root of every key.
const ROOT: &str = "incise/v1";

/// The longest scene name accepted (iceoryx2 service names are limited to 255 bytes in all).
pub const MAX_SCENE_NAME: usize = 64;

/// A scene name that cannot be used in keys.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BadSceneName(pub String);

impl fmt::Display for BadSceneName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "scene name {:?} cannot name keys: use 1 to {MAX_SCENE_NAME} letters, digits, '_' or '-'",
            self.0
        )
    }
}

impl std::error::Error for BadSceneName {}

/// The keys of one scene.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Keys {
    scene: String,
}

impl Keys {
    /// The keys of scene `scene`.
    pub fn new(scene: &str) -> Result<Self, BadSceneName> {
        let ok = !scene.is_empty()
            && scene.len() <= MAX_SCENE_NAME
            && scene.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
        if ok { Ok(Self { scene: scene.to_owned() }) } else { Err(BadSceneName(scene.to_owned())) }
    }

    /// The scene's name.
    #[must_use]
    pub fn scene(&self) -> &str {
        &self.scene
    }

    /// Where tool `id`'s poses are published.
    #[must_use]
    pub fn tool_pose(&self, id: u32) -> String {
        format!("{ROOT}/{}/tool/{id}/pose", self.scene)
    }

    /// Every tool's poses (a zenoh subscription).
    #[must_use]
    pub fn any_tool_pose(&self) -> String {
        format!("{ROOT}/{}/tool/*/pose", self.scene)
    }

    /// Where tool `id`'s forces are published.
    #[must_use]
    pub fn tool_force(&self, id: u32) -> String {
        format!("{ROOT}/{}/tool/{id}/force", self.scene)
    }

    /// Per-frame statistics.
    #[must_use]
    pub fn frame(&self) -> String {
        format!("{ROOT}/{}/frame", self.scene)
    }

    /// Cut events.
    #[must_use]
    pub fn cut(&self) -> String {
        format!("{ROOT}/{}/cut", self.scene)
    }

    /// The organ's surface.
    #[must_use]
    pub fn surface(&self) -> String {
        format!("{ROOT}/{}/surface", self.scene)
    }

    /// The event a shared-memory client raises after publishing poses (iceoryx2 event service:
    /// it wakes the server's receiving thread).
    #[must_use]
    pub fn poses_ready(&self) -> String {
        format!("{ROOT}/{}/tool/poses", self.scene)
    }

    /// The scene's description (queried).
    #[must_use]
    pub fn info(&self) -> String {
        format!("{ROOT}/{}/info", self.scene)
    }

    /// The server's statistics (queried).
    #[must_use]
    pub fn stats(&self) -> String {
        format!("{ROOT}/{}/stats", self.scene)
    }

    /// The tool id in a key of [`Self::tool_pose`]'s form, if `key` is one of this scene's.
    #[must_use]
    pub fn tool_of_pose_key(&self, key: &str) -> Option<u32> {
        let rest = key.strip_prefix(ROOT)?.strip_prefix('/')?.strip_prefix(self.scene.as_str())?;
        let id = rest.strip_prefix("/tool/")?.strip_suffix("/pose")?;
        if id.is_empty() || id.starts_with('+') || (id.len() > 1 && id.starts_with('0')) {
            return None;
        }
        id.parse().ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_have_the_documented_form() {
        let k = Keys::new("liver_13k").unwrap();
        assert_eq!(k.tool_pose(3), "incise/v1/liver_13k/tool/3/pose");
        assert_eq!(k.tool_force(3), "incise/v1/liver_13k/tool/3/force");
        assert_eq!(k.any_tool_pose(), "incise/v1/liver_13k/tool/*/pose");
        assert_eq!(k.frame(), "incise/v1/liver_13k/frame");
        assert_eq!(k.cut(), "incise/v1/liver_13k/cut");
        assert_eq!(k.surface(), "incise/v1/liver_13k/surface");
        assert_eq!(k.info(), "incise/v1/liver_13k/info");
        assert_eq!(k.stats(), "incise/v1/liver_13k/stats");
        assert_eq!(k.poses_ready(), "incise/v1/liver_13k/tool/poses");
    }

    #[test]
    fn a_pose_key_gives_back_its_tool_and_nothing_else_does() {
        let k = Keys::new("demo").unwrap();
        for id in [0, 1, 7, 4_000_000_000] {
            assert_eq!(k.tool_of_pose_key(&k.tool_pose(id)), Some(id));
        }
        for key in [
            "incise/v1/demo/tool/1/force",
            "incise/v1/other/tool/1/pose",
            "incise/v1/demo/tool//pose",
            "incise/v1/demo/tool/01/pose",
            "incise/v1/demo/tool/+1/pose",
            "incise/v1/demo/tool/x/pose",
            "incise/v1/demo/tool/99999999999/pose",
            "incise/v2/demo/tool/1/pose",
            "incise/v1/demox/tool/1/pose",
        ] {
            assert_eq!(k.tool_of_pose_key(key), None, "{key}");
        }
    }

    #[test]
    fn scene_names_that_would_break_a_key_are_refused() {
        for bad in ["", "a/b", "a*", "a b", "$x", "a?", "#", &"x".repeat(65), "é"] {
            let err = Keys::new(bad).unwrap_err();
            assert!(err.to_string().contains("cannot name keys"), "{bad}");
        }
        assert!(Keys::new(&"x".repeat(64)).is_ok());
    }
}
