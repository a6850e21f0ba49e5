"""A small Python client for tandem-server: stream a NumPy volume, get the mesh back.

The proof that the gRPC API (proto/tandem/v1/tandem.proto) serves other languages: one
module on Debian's python3-grpcio and python3-protobuf, with stubs generated from the
.proto by Debian's protoc 3.21 and grpc_python_plugin (the .proto uses proto3 `optional`,
which needs protoc >= 3.15: Debian 12's python3-grpc-tools bundles an older protoc and
rejects it). The build does this (`cmake --build build --target tandem_python`, into
build/python/ next to a copy of this file); by hand:

    protoc -I proto --python_out=OUT --grpc_python_out=OUT \\
        --plugin=protoc-gen-grpc_python=/usr/bin/grpc_python_plugin proto/tandem/v1/tandem.proto

Example (volume indexed [z, y, x], as NumPy reads a stack):

    import numpy as np, tandem_client
    z, y, x = np.mgrid[-1:1:64j, -1:1:64j, -1:1:64j]
    vol = (x * x + y * y + z * z).astype(np.float32)
    result = tandem_client.extract(vol, iso=0.5, error=0.002, spacing=(0.03, 0.03, 0.03))
    print(result.metrics.triangles_final)
    result.save("sphere.drc")               # Draco bytes as the server sent them
    tandem_client.draco_to_ply("sphere.drc", "sphere.ply")  # Debian's draco_decoder

Meshes come back Draco-encoded (the server's only mesh format on the wire); `draco_to_ply`
decodes with the `draco_decoder` program (Debian package `draco`) when no Python Draco
binding is at hand.
"""

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Callable, Iterator, List, Optional, Sequence

import grpc
import numpy as np

from tandem.v1 import tandem_pb2 as pb
from tandem.v1 import tandem_pb2_grpc as pb_grpc

# NumPy dtypes the server takes, as little-endian, and their wire names.
_DTYPES = {
    np.dtype(np.uint8): pb.DTYPE_UINT8,
    np.dtype(np.uint16): pb.DTYPE_UINT16,
    np.dtype(np.int16): pb.DTYPE_INT16,
    np.dtype(np.float32): pb.DTYPE_FLOAT32,
}
_SCHEDULES = {
    "none": pb.SCHEDULE_NONE,
    "classical": pb.SCHEDULE_CLASSICAL,
    "tandem": pb.SCHEDULE_TANDEM,
    "tandem-lag": pb.SCHEDULE_TANDEM_LAG,
}
CHUNK_BYTES = 1 << 20  # the C++ client's chunk size: under every server's message limit


@dataclass
class Result:
    """The final mesh (Draco bytes, chunks joined) and the server's FinalMetrics.

    With sealed_chunks, `draco` is empty and `sealed` holds the SealedChunk messages in
    order: each a Draco mesh whose GENERIC uint32 attribute is the vertices' global ids
    (weld them by id for the whole mesh). `session_id` is the stream's id (for Watch).
    """

    draco: bytes
    metrics: "pb.FinalMetrics"
    previews: List["pb.Preview"] = field(default_factory=list)
    sealed: List["pb.SealedChunk"] = field(default_factory=list)
    session_id: str = ""

    def save(self, path: str) -> None:
        with open(path, "wb") as f:
            f.write(self.draco)


def _requests(volume: np.ndarray, config: "pb.SessionConfig") -> Iterator["pb.ExtractRequest"]:
    yield pb.ExtractRequest(config=config)
    for k in range(volume.shape[0]):
        data = volume[k].tobytes()
        for offset in range(0, len(data), CHUNK_BYTES):
            yield pb.ExtractRequest(chunk=pb.SliceChunk(
                slice=k, offset=offset, data=data[offset:offset + CHUNK_BYTES],
                slice_size=len(data)))
    yield pb.ExtractRequest(end=pb.End(slices=volume.shape[0]))


def extract(volume: np.ndarray, iso: float, error: float, server: str = "127.0.0.1:50051",
            spacing: Sequence[float] = (1.0, 1.0, 1.0), origin: Sequence[float] = (0, 0, 0),
            schedule: str = "tandem-lag", target_triangles: int = 0, preview_every: int = 0,
            description: str = "python", sealed_chunks: bool = False,
            token: Optional[str] = None,
            tls_ca: Optional[str] = None, timeout: Optional[float] = None,
            on_progress: Optional[Callable[["pb.Progress"], None]] = None) -> Result:
    """Streams `volume` ([z, y, x]: slice k is volume[k]) and returns the mesh.

    spacing and origin are (x, y, z), in the physical units E0 (`error`) is in. Raises
    ValueError for a volume the server cannot take, grpc.RpcError with the server's
    status (INVALID_ARGUMENT, RESOURCE_EXHAUSTED, ... and a message naming the problem).
    """
    volume = np.asarray(volume)
    if volume.ndim != 3 or min(volume.shape) < 2:
        raise ValueError(f"volume must be 3-D with at least 2 voxels per axis, got {volume.shape}")
    native = volume.dtype.newbyteorder("=")
    if native not in _DTYPES:
        raise ValueError(f"dtype {volume.dtype} is not one of uint8, uint16, int16, float32 "
                         "(convert it, e.g. volume.astype(np.float32))")
    if schedule not in _SCHEDULES:
        raise ValueError(f"schedule {schedule!r} is not one of {', '.join(_SCHEDULES)}")
    volume = np.ascontiguousarray(volume, dtype=native.newbyteorder("<"))
    nz, ny, nx = volume.shape
    config = pb.SessionConfig(
        nx=nx, ny=ny, nz=nz, dtype=_DTYPES[native], spacing=list(spacing), origin=list(origin),
        iso=iso, error=error, schedule=_SCHEDULES[schedule], target_triangles=target_triangles,
        preview=pb.PreviewCadence(every_slices=preview_every), description=description,
        sealed_chunks=sealed_chunks)
    if tls_ca is not None:
        with open(tls_ca, "rb") as f:
            channel = grpc.secure_channel(server, grpc.ssl_channel_credentials(f.read()))
    else:
        channel = grpc.insecure_channel(server)
    metadata = [("authorization", f"Bearer {token}")] if token else None
    chunks: List[bytes] = []
    previews: List[pb.Preview] = []
    sealed: List[pb.SealedChunk] = []
    session_id = ""
    metrics = None
    with channel:
        stub = pb_grpc.TandemStub(channel)
        for response in stub.Extract(_requests(volume, config), metadata=metadata,
                                     timeout=timeout):
            kind = response.WhichOneof("kind")
            if kind == "progress":
                session_id = session_id or response.progress.session_id
                if on_progress is not None:
                    on_progress(response.progress)
            elif kind == "sealed_chunk":
                if response.sealed_chunk.index != len(sealed):
                    raise RuntimeError("sealed chunks out of order")
                sealed.append(response.sealed_chunk)
            elif kind == "preview":
                previews.append(response.preview)
            elif kind == "final_mesh":
                if response.final_mesh.chunk_index != len(chunks):
                    raise RuntimeError("final mesh chunks out of order")
                chunks.append(response.final_mesh.draco)
            elif kind == "final_metrics":
                metrics = response.final_metrics
    if metrics is None:
        raise RuntimeError("the stream ended without final metrics")
    return Result(draco=b"".join(chunks), metrics=metrics, previews=previews, sealed=sealed,
                  session_id=session_id)


def draco_to_ply(draco_path: str, ply_path: str) -> None:
    """Decodes a .drc file to PLY with Debian's draco_decoder (package `draco`)."""
    decoder = shutil.which("draco_decoder")
    if decoder is None:
        raise RuntimeError("draco_decoder not found (apt-get install draco)")
    subprocess.run([decoder, "-i", draco_path, "-o", ply_path], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _main(argv: Sequence[str]) -> int:
    import argparse
    parser = argparse.ArgumentParser(
        description="Stream a NumPy volume (.npy, indexed [z, y, x]) to tandem-server and "
                    "write the mesh (.drc as sent, or .ply through draco_decoder).")
    parser.add_argument("--server", default=os.environ.get("TANDEM_SERVER", "127.0.0.1:50051"))
    parser.add_argument("--input", required=True, help="volume .npy")
    parser.add_argument("--iso", type=float, required=True)
    parser.add_argument("--error", type=float, required=True)
    parser.add_argument("--spacing", default="1,1,1", help="x,y,z")
    parser.add_argument("--schedule", default="tandem-lag", choices=sorted(_SCHEDULES))
    parser.add_argument("--out", required=True, help="mesh .drc or .ply")
    args = parser.parse_args(argv)
    spacing = [float(v) for v in args.spacing.split(",")]
    if len(spacing) != 3:
        parser.error("--spacing takes three numbers x,y,z")
    try:
        result = extract(np.load(args.input), args.iso, args.error, server=args.server,
                         spacing=spacing, schedule=args.schedule,
                         description=os.path.basename(args.input),
                         token=os.environ.get("TANDEM_TOKEN"))
    except grpc.RpcError as e:
        print(f"tandem_client: {e.code().name}: {e.details()}", file=sys.stderr)
        return 1
    except ValueError as e:
        print(f"tandem_client: {e}", file=sys.stderr)
        return 2
    if args.out.endswith(".ply"):
        drc = args.out[:-4] + ".drc"
        result.save(drc)
        draco_to_ply(drc, args.out)
    else:
        result.save(args.out)
    m = result.metrics
    print(f"{m.triangles_final} triangles, {m.vertices_final} vertices "
          f"({m.triangles_extracted} extracted); wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
