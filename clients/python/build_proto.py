"""Generates the incise.v1 message classes from protocol/proto into clients/python/generated/,
with the protoc that grpcio-tools bundles (no protoc on the machine). Run once after installing
requirements.txt; incise_client.py runs it itself when the classes are missing or older than
a .proto file."""

import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
PROTO = HERE.parent.parent / "protocol" / "proto"
OUT = HERE / "generated"


def stale() -> bool:
    """Whether the classes are missing or older than a .proto file."""
    marker = OUT / "incise" / "v1" / "tool_pb2.py"
    if not marker.exists():
        return True
    built = marker.stat().st_mtime
    return any(p.stat().st_mtime > built for p in (PROTO / "incise" / "v1").glob("*.proto"))


def build() -> pathlib.Path:
    from grpc_tools import protoc

    OUT.mkdir(exist_ok=True)
    files = sorted(str(p) for p in (PROTO / "incise" / "v1").glob("*.proto"))
    status = protoc.main(["protoc", f"-I{PROTO}", f"--python_out={OUT}", *files])
    if status != 0:
        sys.exit(f"protoc failed ({status}) on {files}")
    return OUT


if __name__ == "__main__":
    print(build())
