"""An incise client in Python: zenoh and the .proto files only.

    python incise_client.py --connect tcp/127.0.0.1:7447 --scene demo_organ --tool 1 --json

connects to a running incise-server, asks for its scene, lowers the tool onto the organ's top
centre at 1 kHz until the tissue pushes back, and prints what came back (with --json, one JSON
line last: poses sent, forces answered, the first force in contact).
"""

import argparse
import json
import pathlib
import queue
import random
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import build_proto  # noqa: E402

if build_proto.stale():
    build_proto.build()
sys.path.insert(0, str(HERE / "generated"))

import zenoh  # noqa: E402
from incise.v1 import scene_pb2, tool_pb2  # noqa: E402

IN_CONTACT = 1


class InciseClient:
    """One tool of a scene served at `endpoint` (tcp/HOST:PORT)."""

    def __init__(self, endpoint: str, scene: str, tool: int):
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.tool = tool
        # This connection's session: the server lets one session drive a tool at a time.
        self.client = random.randint(1, 2**32 - 1)
        self.root = f"incise/v1/{scene}"
        self.forces: "queue.Queue[tool_pb2.ToolForce]" = queue.Queue()
        self.publisher = self.session.declare_publisher(f"{self.root}/tool/{tool}/pose")
        self.subscriber = self.session.declare_subscriber(
            f"{self.root}/tool/{tool}/force", self._on_force
        )

    def _on_force(self, sample) -> None:
        force = tool_pb2.ToolForce()
        force.ParseFromString(bytes(sample.payload.to_bytes()))
        self.forces.put(force)

    def scene_info(self, timeout: float = 5.0) -> scene_pb2.SceneInfo:
        for reply in self.session.get(f"{self.root}/info", timeout=timeout):
            if reply.ok is not None:
                info = scene_pb2.SceneInfo()
                info.ParseFromString(bytes(reply.ok.payload.to_bytes()))
                return info
        raise TimeoutError(f"no server answered {self.root}/info")

    def send_pose(self, sequence: int, position, orientation=(1.0, 0.0, 0.0, 0.0), gripper=0.0):
        pose = tool_pb2.ToolPose(
            tool_id=self.tool,
            sequence=sequence,
            timestamp_ns=time.monotonic_ns(),
            position=tool_pb2.Vec3(x=position[0], y=position[1], z=position[2]),
            orientation=tool_pb2.Quaternion(
                w=orientation[0], x=orientation[1], y=orientation[2], z=orientation[3]
            ),
            gripper_angle=gripper,
            client=self.client,
        )
        self.publisher.put(pose.SerializeToString())

    def recv_force(self, timeout: float):
        try:
            return self.forces.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self.session.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", default="tcp/127.0.0.1:7447")
    parser.add_argument("--scene", default="demo_organ")
    parser.add_argument("--tool", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    client = InciseClient(args.connect, args.scene, args.tool)
    deadline = time.monotonic() + 30
    while True:
        try:
            info = client.scene_info(timeout=1.0)
            break
        except TimeoutError:
            if time.monotonic() > deadline:
                raise
    x = (info.bounds_min_x + info.bounds_max_x) / 2
    y = (info.bounds_min_y + info.bounds_max_y) / 2
    top = info.bounds_max_z
    sent = answered = 0
    contact = None
    for sequence in range(1, 40001):
        z = top + 0.01 - 0.001 * (sequence // 40)  # from 1 cm above, 1 mm per 40 poses
        client.send_pose(sequence, (x, y, z))
        sent += 1
        until = time.monotonic() + 0.002
        while (left := until - time.monotonic()) > 0:
            force = client.recv_force(left)
            if force is None:
                break
            if force.pose_sequence == sequence:
                answered += 1
                if force.force.z != 0.0 and force.flags & IN_CONTACT:
                    contact = {"sequence": sequence, "z": z, "force": [force.force.x, force.force.y, force.force.z]}
                break
        if contact:
            break
    client.close()
    summary = {"scene": info.scene, "tools": len(info.tools), "sent": sent, "answered": answered, "contact": contact}
    print(f"{info.scene}: {sent} poses sent, {answered} answered; in contact: {contact}")
    if args.json:
        print(json.dumps(summary))
    return 0 if contact else 1


if __name__ == "__main__":
    sys.exit(main())
