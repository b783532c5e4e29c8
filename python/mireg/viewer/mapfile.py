"""Reading the world map written by ``mireg map OUT.mcap -o map.ply|.pcd|.npy``.

mireg writes binary little-endian PLY with ``float`` vertex properties ``x y z [intensity]``, PCD
v0.7 ``DATA binary`` with ``F 4`` fields, and ``.npy`` float32 (N, 3) or (N, 4). This reader takes
those and a little more (ASCII PLY/PCD, big-endian PLY, any scalar types, extra properties);
``binary_compressed`` PCD and PLY vertices with list properties are refused with a message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class MapFileError(SystemExit):
    """The map file cannot be read (a message, exit status 1)."""


def load_map(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (float64 N×3, finite only) and intensity (N, or None) of a map file."""
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"--map {path}: no such file")
    ext = path.suffix.lower()
    try:
        if ext == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.ndim != 2 or arr.shape[1] not in (3, 4):
                raise ValueError(f"shape {arr.shape} is not (N, 3) or (N, 4)")
            cols = {"x": arr[:, 0], "y": arr[:, 1], "z": arr[:, 2]}
            if arr.shape[1] == 4:
                cols["intensity"] = arr[:, 3]
        elif ext == ".ply":
            cols = _read_ply(path.read_bytes())
        elif ext == ".pcd":
            cols = _read_pcd(path.read_bytes())
        else:
            raise ValueError(f"unknown extension {ext!r} (expected .ply, .pcd or .npy)")
    except (ValueError, KeyError, IndexError) as e:
        raise MapFileError(f"--map {path}: {e}") from None
    for axis in "xyz":
        if axis not in cols:
            raise MapFileError(f"--map {path}: no {axis!r} field")
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)
    keep = np.isfinite(xyz).all(axis=1)
    intensity = cols.get("intensity")
    if intensity is not None:
        intensity = np.asarray(intensity, dtype=np.float64)[keep]
    return xyz[keep], intensity


def _read_ply(data: bytes) -> dict:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file (no 'ply' magic or 'end_header')")
    body_start = data.index(b"\n", end) + 1
    fmt, elements = None, []  # elements: [name, count, [(prop, type or None for a list)]]
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if words[1] == "list":
                elements[-1][2].append((words[4], None))
            else:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
    body = data[body_start:]
    if fmt == "ascii":
        lines = body.decode("ascii").split("\n")
        row = 0
        for name, count, props in elements:
            if name == "vertex":
                if any(t is None for _, t in props):
                    raise ValueError("ASCII PLY vertex with list properties is not supported")
                table = np.array([lines[row + i].split()[: len(props)] for i in range(count)],
                                 dtype=np.float64).reshape(count, len(props))
                return {p: table[:, j] for j, (p, _) in enumerate(props)}
            row += count
        raise ValueError("PLY header has no 'element vertex'")
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise ValueError(f"PLY format {fmt!r} is not supported")
    endian = "<" if fmt == "binary_little_endian" else ">"
    offset = 0
    for name, count, props in elements:
        if any(t is None for _, t in props):
            raise ValueError(f"PLY element {name!r} has list properties (not supported)")
        dtype = np.dtype([(p, endian + t) for p, t in props])
        if name == "vertex":
            arr = np.frombuffer(body, dtype=dtype, count=count, offset=offset)
            return {p: arr[p] for p, _ in props}
        offset += dtype.itemsize * count
    raise ValueError("PLY header has no 'element vertex'")


def _read_pcd(data: bytes) -> dict:
    header, pos = {}, 0
    while True:
        nl = data.index(b"\n", pos)
        line = data[pos:nl].decode("ascii", "replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    fields = header["FIELDS"]
    sizes = [int(s) for s in header["SIZE"]]
    types = header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = int(header["POINTS"][0])
    kind = header["DATA"][0]
    if kind == "ascii":
        rows = data[pos:].decode("ascii").split("\n")[:n]
        table = np.array([r.split() for r in rows], dtype=np.float64).reshape(n, -1)
        out, col = {}, 0
        for f, c in zip(fields, counts):
            out[f] = table[:, col]
            col += c
        return out
    if kind != "binary":
        raise ValueError(f"PCD DATA {kind} is not supported (ascii and binary are)")
    dtype = np.dtype([(f if f != "_" else f"_pad{i}", f"<{t.lower()}{s}", (c,) if c > 1 else ())
                      for i, (f, s, t, c) in enumerate(zip(fields, sizes, types, counts))])
    arr = np.frombuffer(data, dtype=dtype, count=n, offset=pos)
    return {f: arr[f] for f in fields if f != "_" and arr[f].ndim == 1}
