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
    result.vertices, result.faces           # NumPy arrays: (N, 3) float32, (M, 3) uint32
    result.write("sphere.stl")              # .ply, .obj, .stl, or .drc as the server sent it

Meshes come back Draco-encoded (the server's only mesh format on the wire); they are decoded
with the `draco_decoder` program (Debian package `draco`), as no Python Draco binding is
packaged. Sealed chunks are welded by position: a stream quantizes all its chunks on one grid,
so a vertex two chunks share decodes to the same coordinates in both.
"""

import os
import shutil
import struct
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Tuple

import grpc
import numpy as np

from tandem.v1 import tandem_pb2 as pb
from tandem.v1 import tandem_pb2_grpc as pb_grpc

# NumPy dtypes the server takes, as little-endian, and their wire names.
_DTYPES = {
    np.dtype(np.uint8): pb.DTYPE_UINT8,
    np.dtype(np.int8): pb.DTYPE_INT8,
    np.dtype(np.uint16): pb.DTYPE_UINT16,
    np.dtype(np.int16): pb.DTYPE_INT16,
    np.dtype(np.uint32): pb.DTYPE_UINT32,
    np.dtype(np.int32): pb.DTYPE_INT32,
    np.dtype(np.uint64): pb.DTYPE_UINT64,
    np.dtype(np.int64): pb.DTYPE_INT64,
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
    order: each a Draco mesh whose GENERIC uint32 attribute is the vertices' global ids.
    `vertices` and `faces` decode either into NumPy arrays. `session_id` is the stream's id
    and `watch_key` the secret that lets others read it (Watch, GetInfo): sessions are
    private to their creator's bearer token and to those given the key.
    """

    draco: bytes
    metrics: "pb.FinalMetrics"
    previews: List["pb.Preview"] = field(default_factory=list)
    sealed: List["pb.SealedChunk"] = field(default_factory=list)
    session_id: str = ""
    watch_key: str = ""
    # labels=True: each label's own Result (its mesh and its FinalMetrics, whose `label` and
    # `label_figures` say which and what), by label id; `metrics` is then the whole session's.
    labels: Dict[int, "Result"] = field(default_factory=dict)
    _mesh: Optional[Tuple[np.ndarray, np.ndarray]] = field(default=None, repr=False)

    def save(self, path: str) -> None:
        """Writes the Draco bytes as the server sent them (unsealed streams)."""
        if not self.draco:
            raise ValueError("a sealed stream has no single Draco mesh: use write() with "
                             ".ply, .obj or .stl")
        with open(path, "wb") as f:
            f.write(self.draco)

    def _decoded(self) -> Tuple[np.ndarray, np.ndarray]:
        if self._mesh is None:
            if self.sealed:
                self._mesh = weld_by_position([decode_draco(c.draco) for c in self.sealed])
            else:
                self._mesh = decode_draco(self.draco)
        return self._mesh

    @property
    def vertices(self) -> np.ndarray:
        """(N, 3) float32 vertex positions, in the volume's physical units."""
        return self._decoded()[0]

    @property
    def faces(self) -> np.ndarray:
        """(M, 3) uint32 vertex indices, counter-clockwise seen from outside."""
        return self._decoded()[1]

    def write(self, path: str) -> None:
        """Writes the mesh in the format `path`'s extension names (MESH_FORMATS)."""
        ext = check_mesh_path(path)
        if ext == ".drc":
            self.save(path)
        else:
            write_mesh(path, self.vertices, self.faces)


# What write() and the command line's --out take; anything else is refused before streaming.
MESH_FORMATS = (".drc", ".ply", ".obj", ".stl")


def check_mesh_path(path: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_FORMATS:
        raise ValueError(f"{path}: the output format is named by its extension, one of "
                         f"{', '.join(MESH_FORMATS)} (for .glb use `tandem-client stream`)")
    return ext


def _read_ply(path: str) -> Tuple[np.ndarray, np.ndarray]:
    """Positions and triangles of a binary little-endian PLY as draco_decoder writes it."""
    types = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
             "uint": "<u4", "float": "<f4", "double": "<f8"}
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    elements = []  # [name, count, [(prop, dtype)] or ("list", count type, index type)]
    for line in data[:end].decode("ascii").splitlines():
        words = line.split()
        if words[:1] == ["format"] and words[1] != "binary_little_endian":
            raise RuntimeError(f"{path}: PLY format {words[1]} (expected binary_little_endian)")
        if words[:1] == ["element"]:
            elements.append([words[1], int(words[2]), []])
        elif words[:2] == ["property", "list"]:
            elements[-1][2] = ("list", types[words[2]], types[words[3]])
        elif words[:1] == ["property"]:
            elements[-1][2].append((words[2], types[words[1]]))
    offset, vertices, faces = end, None, None
    for name, count, props in elements:
        if props and props[0] == "list":
            row = np.dtype([("n", props[1]), ("i", props[2], 3)])
            rows = np.frombuffer(data, row, count, offset)
            if count and not (rows["n"] == 3).all():
                raise RuntimeError(f"{path}: a face that is not a triangle")
            offset += row.itemsize * count
            if name == "face":
                faces = rows["i"].astype(np.uint32)
        else:
            row = np.dtype(props)
            rows = np.frombuffer(data, row, count, offset)
            offset += row.itemsize * count
            if name == "vertex":
                vertices = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float32)
    if vertices is None or faces is None:
        raise RuntimeError(f"{path}: no vertex or face element")
    return vertices, faces


def decode_draco(data: bytes) -> Tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float32, faces (M, 3) uint32) of a Draco mesh, by draco_decoder."""
    decoder = shutil.which("draco_decoder")
    if decoder is None:
        raise RuntimeError("draco_decoder not found (apt-get install draco)")
    with tempfile.TemporaryDirectory(prefix="tandem-draco-") as tmp:
        drc, ply = os.path.join(tmp, "m.drc"), os.path.join(tmp, "m.ply")
        with open(drc, "wb") as f:
            f.write(data)
        subprocess.run([decoder, "-i", drc, "-o", ply], check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE)
        return _read_ply(ply)


def weld_by_position(meshes: Sequence[Tuple[np.ndarray, np.ndarray]]
                     ) -> Tuple[np.ndarray, np.ndarray]:
    """One mesh of several, vertices at the same position made one."""
    if not meshes:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    positions = np.concatenate([v for v, _ in meshes])
    starts = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    faces = np.concatenate([f.astype(np.int64) + s for (_, f), s in zip(meshes, starts)])
    unique, inverse = np.unique(positions, axis=0, return_inverse=True)
    return unique.astype(np.float32), inverse.reshape(-1)[faces].astype(np.uint32)


def write_mesh(path: str, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary PLY, OBJ or binary STL (facet normals), by `path`'s extension."""
    ext = check_mesh_path(path)
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.uint32)
    if ext == ".ply":
        header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  f"element face {len(f)}\nproperty list uchar uint vertex_indices\n"
                  "end_header\n")
        rows = np.empty(len(f), np.dtype([("n", "u1"), ("i", "<u4", 3)]))
        rows["n"], rows["i"] = 3, f
        with open(path, "wb") as out:
            out.write(header.encode("ascii"))
            out.write(v.astype("<f4").tobytes())
            out.write(rows.tobytes())
    elif ext == ".obj":
        with open(path, "w") as out:
            out.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in v))
            out.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    elif ext == ".stl":
        corners = v[f.astype(np.int64)]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
        rows = np.zeros(len(f), np.dtype([("n", "<f4", 3), ("c", "<f4", (3, 3)), ("a", "<u2")]))
        rows["n"], rows["c"] = normals, corners
        with open(path, "wb") as out:
            out.write(b"binary STL written by tandem_client".ljust(80, b" "))
            out.write(struct.pack("<I", len(f)))
            out.write(rows.tobytes())
    else:
        raise ValueError(f"{path}: write_mesh writes .ply, .obj or .stl")


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
            labels: bool = False, background: int = 0, label_ids: Sequence[int] = (),
            close: bool = False,
            token: Optional[str] = None,
            tls_ca: Optional[str] = None, timeout: Optional[float] = None,
            on_progress: Optional[Callable[["pb.Progress"], None]] = None) -> Result:
    """Streams `volume` ([z, y, x]: slice k is volume[k]) and returns the mesh.

    spacing and origin are (x, y, z), in the physical units E0 (`error`) is in. labels=True:
    the volume is a label map (integer ids; `iso` is not used): every label other than
    `background` (or those of `label_ids`) gets its surface in Result.labels, closed at the
    volume's border with `close` (tandem.proto: LabelConfig). Raises
    ValueError for a volume the server cannot take, grpc.RpcError with the server's
    status (INVALID_ARGUMENT, RESOURCE_EXHAUSTED, ... and a message naming the problem).
    """
    volume = np.asarray(volume)
    if volume.ndim != 3 or min(volume.shape) < 2:
        raise ValueError(f"volume must be 3-D with at least 2 voxels per axis, got {volume.shape}")
    native = volume.dtype.newbyteorder("=")
    if native not in _DTYPES:
        raise ValueError(f"dtype {volume.dtype} is not one of "
                         f"{', '.join(str(d) for d in _DTYPES)} "
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
    if labels:
        config.labels.CopyFrom(pb.LabelConfig(enabled=True, background=background,
                                              only=sorted(label_ids), close=close))
    if tls_ca is not None:
        with open(tls_ca, "rb") as f:
            channel = grpc.secure_channel(server, grpc.ssl_channel_credentials(f.read()))
    else:
        channel = grpc.insecure_channel(server)
    metadata = [("authorization", f"Bearer {token}")] if token else None
    chunks: List[bytes] = []
    previews: List[pb.Preview] = []
    sealed: List[pb.SealedChunk] = []
    session_id = watch_key = ""
    metrics = None
    label_chunks: Dict[int, List[bytes]] = {}  # a label session's meshes, by label id
    per_label: Dict[int, Result] = {}
    with channel:
        stub = pb_grpc.TandemStub(channel)
        for response in stub.Extract(_requests(volume, config), metadata=metadata,
                                     timeout=timeout):
            kind = response.WhichOneof("kind")
            if kind == "progress":
                session_id = session_id or response.progress.session_id
                watch_key = watch_key or response.progress.watch_key
                if on_progress is not None:
                    on_progress(response.progress)
            elif kind == "sealed_chunk":
                if response.sealed_chunk.index != len(sealed):
                    raise RuntimeError("sealed chunks out of order")
                sealed.append(response.sealed_chunk)
            elif kind == "preview":
                previews.append(response.preview)
            elif kind == "final_mesh":
                mesh = response.final_mesh
                into = label_chunks.setdefault(mesh.label, []) if mesh.HasField("label") \
                    else chunks
                if mesh.chunk_index != len(into):
                    raise RuntimeError("final mesh chunks out of order")
                into.append(mesh.draco)
            elif kind == "final_metrics":
                if response.final_metrics.HasField("label"):
                    m = response.final_metrics
                    per_label[m.label] = Result(draco=b"".join(label_chunks.get(m.label, [])),
                                                metrics=m)
                else:
                    metrics = response.final_metrics
    if metrics is None:
        raise RuntimeError("the stream ended without final metrics")
    return Result(draco=b"".join(chunks), metrics=metrics, previews=previews, sealed=sealed,
                  session_id=session_id, watch_key=watch_key, labels=per_label)


def draco_to_ply(draco_path: str, ply_path: str) -> None:
    """Decodes a .drc file to PLY with Debian's draco_decoder (package `draco`)."""
    with open(draco_path, "rb") as f:
        write_mesh(ply_path, *decode_draco(f.read()))


def _main(argv: Sequence[str]) -> int:
    import argparse
    parser = argparse.ArgumentParser(
        description="Stream a NumPy volume (.npy, indexed [z, y, x]) to tandem-server and "
                    "write the mesh in the format --out names (.drc as sent, .ply, .obj, .stl).")
    parser.add_argument("--server", default=os.environ.get("TANDEM_SERVER", "127.0.0.1:50051"))
    parser.add_argument("--input", required=True, help="volume .npy")
    parser.add_argument("--iso", type=float, help="the iso-value (not with --labels)")
    parser.add_argument("--error", type=float, required=True)
    parser.add_argument("--spacing", default="1,1,1", help="x,y,z")
    parser.add_argument("--schedule", default="tandem-lag", choices=sorted(_SCHEDULES))
    parser.add_argument("--out", required=True, help="mesh: " + ", ".join(MESH_FORMATS) +
                        "; with --labels a folder DIR/, written DIR/<id>.ply per label")
    parser.add_argument("--labels", action="store_true",
                        help="the volume is a label map: one surface per label")
    parser.add_argument("--background", type=int, default=0,
                        help="--labels: the label with no surface of its own")
    parser.add_argument("--label-ids", default="", help="--labels: mesh these labels only (A,B,...)")
    parser.add_argument("--close", action="store_true",
                        help="--labels: close the surfaces at the volume's border")
    args = parser.parse_args(argv)
    if args.labels == (args.iso is not None):
        parser.error("give --iso, or --labels (a label map), not both")
    spacing = [float(v) for v in args.spacing.split(",")]
    if len(spacing) != 3:
        parser.error("--spacing takes three numbers x,y,z")
    try:
        if args.labels:
            label_ids = [int(v) for v in args.label_ids.split(",") if v.strip()]
            if not args.out.endswith("/"):
                raise ValueError(f"--labels --out {args.out}: give a folder, ending in /")
        else:
            check_mesh_path(args.out)  # before anything is streamed
    except ValueError as e:
        parser.error(str(e))
    try:
        result = extract(np.load(args.input), args.iso or 0.0, args.error, server=args.server,
                         spacing=spacing, schedule=args.schedule,
                         description=os.path.basename(args.input),
                         token=os.environ.get("TANDEM_TOKEN"), labels=args.labels,
                         background=args.background, label_ids=label_ids if args.labels else (),
                         close=args.close)
        if args.labels:
            os.makedirs(args.out, exist_ok=True)
            for label, one in sorted(result.labels.items()):
                one.write(os.path.join(args.out, f"{label}.ply"))
        else:
            result.write(args.out)
    except grpc.RpcError as e:
        print(f"tandem_client: {e.code().name}: {e.details()}", file=sys.stderr)
        return 1
    except (ValueError, OSError, RuntimeError, subprocess.CalledProcessError) as e:
        print(f"tandem_client: {e}", file=sys.stderr)  # the input or a failure: exit 1
        return 1
    m = result.metrics
    labels = f" in {len(result.labels)} labels" if args.labels else ""
    print(f"{m.triangles_final} triangles, {m.vertices_final} vertices "
          f"({m.triangles_extracted} extracted){labels}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
