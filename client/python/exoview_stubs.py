"""Python stubs for the Exoview wire format, generated from the unchanged proto/exoview.proto.

Nothing generated is committed: load() compiles the .proto files with Debian's
python3-grpc-tools (`python3 -m grpc_tools.protoc`) into a directory (the build tree when CMake
passes --stubs, else a temporary one) and puts it on sys.path.
"""
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
EXOVIEW_PROTO = os.path.join(HERE, "..", "..", "proto", "exoview.proto")
REFLECTION_PROTO = os.path.join(HERE, "grpc_reflection_v1alpha.proto")


def generate(out_dir):
    """Runs grpc_tools.protoc on exoview.proto and the reflection proto into out_dir."""
    os.makedirs(out_dir, exist_ok=True)
    for proto in (EXOVIEW_PROTO, REFLECTION_PROTO):
        proto = os.path.normpath(proto)
        cmd = [sys.executable, "-m", "grpc_tools.protoc", "-I" + os.path.dirname(proto),
               "--python_out=" + out_dir, "--grpc_python_out=" + out_dir, proto]
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError("grpc_tools.protoc failed on %s:\n%s" % (proto, result.stderr))


def load(stubs_dir=None):
    """Makes `import exoview_pb2, exoview_pb2_grpc` work; generates the stubs when missing."""
    if stubs_dir is None:
        stubs_dir = tempfile.mkdtemp(prefix="exoview_stubs_")
    needed = ("exoview_pb2.py", "exoview_pb2_grpc.py", "grpc_reflection_v1alpha_pb2.py")
    if not all(os.path.exists(os.path.join(stubs_dir, n)) for n in needed):
        generate(stubs_dir)
    if stubs_dir not in sys.path:
        sys.path.insert(0, stubs_dir)


if __name__ == "__main__":
    # python3 exoview_stubs.py OUT_DIR: generate (used by CMake at build time).
    if len(sys.argv) != 2:
        sys.exit("usage: exoview_stubs.py OUT_DIR")
    generate(sys.argv[1])
