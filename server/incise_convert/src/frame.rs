//! A stepped frame as the messages the server publishes and records.

use incise_protocol::raw::RawToolPose;
use incise_protocol::v1::{self, ForceFlag};
use incise_sim::{Frame, Simulation};
use std::time::Duration;

/// What the recording keeps of a frame: the poses it used, each tool's force and contact, the
/// hash of the state it left, its statistics.
#[must_use]
pub fn frame_record(frame: &Frame, used: &[RawToolPose], stats: v1::FrameStats) -> v1::FrameRecord {
    let vec3 = |v: [f64; 3]| Some(v1::Vec3 { x: v[0], y: v[1], z: v[2] });
    let tools = frame
        .surgical
        .tools
        .iter()
        .enumerate()
        .filter(|(_, t)| t.pose.is_some())
        .map(|(i, t)| v1::ToolState {
            tool_id: i as u32,
            force: vec3(t.linearisation.force),
            torque: vec3(t.linearisation.torque),
            flags: tool_flags(frame, i),
            contact_points: t.contact_points as u32,
            held_points: t.held_points as u32,
            proxy: t.proxy.map(|p| v1::Pose::of(p.position(), p.rotation())),
        })
        .collect();
    v1::FrameRecord {
        frame: frame.index,
        sim_time_s: frame.time,
        poses: used.iter().map(v1::ToolPose::from).collect(),
        tools,
        state_hash: frame.state_hash,
        stats: Some(stats),
    }
}

/// A cut `frame` made, as its message.
#[must_use]
pub fn cut_event(frame: &Frame, cut: &incise_sim::CutEvent) -> v1::CutEvent {
    v1::CutEvent {
        frame: frame.index,
        tool_id: cut.tool as u32,
        voxels_removed: cut.voxels_removed as u32,
        links_severed: cut.links_severed as u32,
        tets_removed: cut.tets_removed as u32,
    }
}

/// Tool `i`'s force flags at `frame`: in contact, cutting.
#[must_use]
pub fn tool_flags(frame: &Frame, i: usize) -> u32 {
    let tool = &frame.surgical.tools[i];
    let mut flags = 0;
    if tool.contact_points > 0 || tool.held_points > 0 {
        flags |= ForceFlag::InContact as u32;
    }
    if frame.surgical.cuts.iter().any(|c| c.tool == i) {
        flags |= ForceFlag::Cutting as u32;
    }
    flags
}

/// A frame's statistics: its stage times, what it touched and cut, the surface's size, and
/// `rate` (frames per second of wall time).
#[must_use]
pub fn frame_stats(frame: &Frame, sim: &Simulation, wall: Duration, rate: f64) -> v1::FrameStats {
    let c = &frame.counters;
    let ms = |ns: u64| ns as f64 * 1e-6;
    v1::FrameStats {
        frame: frame.index,
        sim_time_s: frame.time,
        frame_ms: wall.as_secs_f64() * 1e3,
        contact_ms: ms(c.contact_ns),
        cut_ms: ms(c.cut_ns),
        grid_ms: ms(c.grid_ns),
        remesh_ms: ms(c.remesh_ns),
        mechanics_ms: ms(c.mechanics_ns),
        contact_points: c.contact_points as u32,
        voxels_removed: c.voxels_removed as u32,
        links_severed: c.links_severed as u32,
        tets_removed: c.tets_removed as u32,
        triangles: sim.surface().map_or(0, incise_sim::OrganSurface::triangle_count) as u32,
        frame_rate_hz: rate,
        solver_iterations: c.solver_iterations as u32,
    }
}
