#!/usr/bin/env python3
"""MeshLab's ambient occlusion on the data mvao shades, for comparison.

    compare_pymeshlab.py SCAN.ply... [--align FILE] -o OUTDIR [--dirs N] [--min-hit D]
                         [--max-edge-factor F] [--csv FILE --label L] [--force]
    compare_pymeshlab.py --selftest [--dirs N]

Reads the PLY scans, places them in world coordinates with the alignment file (the formats and
conventions of `mvao merge`: Stanford `.conf` with world = R(q)^T p + t, MeshLab `.mlp`, JSON),
turns every scan into triangles (its own faces, or its native range grid), runs pymeshlab's
`compute_scalar_ambient_occlusion` once on the union of all scans, maps the result to mvao's
convention (a in [0, 1], 1 = open) and writes per scan `OUTDIR/<stem>.pymeshlab.ply` (binary
little-endian; the scan's vertices in input order, `x y z` exactly as read, `float ao`) and
`OUTDIR/pymeshlab.json` (timings, directions, the mapping, points in no triangle).
scripts/README.md has the details and the measurements; the essentials follow.

The filter (MeshLab's Embree plugin, CPU, OpenMP). `rays` = N directions w on the whole
sphere (spherical Fibonacci). From each face's barycentre it casts a ray along every w with
n.w > 0 (about N/2 rays, unbounded, hits nearer than 1e-5 scene units ignored) and sums n.w
over the rays that hit nothing; a vertex gets the area-weighted mean of its faces:

    Q_f = sum over unoccluded w with n_f.w > 0 of n_f.w,    q_v = sum_f |f| Q_f / sum_f |f|

The mapping. An open face has Q_f = D_f = sum_w max(n_f.w, 0), about N/4 but normal-dependent,
so each face is divided by its own D_f (same directions, the filter's face normals) before the
filter's own area-weighted vertex step:

    a_f = clamp(Q_f / D_f, 0, 1),    a_v = sum_f |f| a_f / sum_f |f|

a_v is the cosine-weighted visible fraction of the hemisphere: the obscurance with
t_max = infinity. Measured with --selftest (pymeshlab 2025.7.post1; query vertex values):

    scene                                   raw q_v N=64   a N=64   a N=256  a N=1024  ideal
    open plane (every vertex)               16.000         1.000    1.000    1.000     1
    closed unit box, floor centre           0.000          0.000    0.000    0.000     0
    open unit box, floor centre             3.750          0.234    0.249    0.241     0.2395
    floor at the foot of a 20 x 10 m wall   8.281          0.518    0.511    0.511     0.5 (+)
    wall-wall-floor corner (10 m walls)     4.859          0.304    0.270    0.264     0.25 (+)
    D_f / (N/4), 2000 random normals                       0.985-1.012 (N=64), 0.9996-1.0004
                                                           (N=1024)

(+) finite walls: the exact values are about 0.01 higher. The open box's value is the form
factor of its opening, 4 (1/2pi) 2 (A/sqrt(1+A^2)) atan(A/sqrt(1+A^2)), A = 1/2. The filter's
q_v equals the area-weighted mean of its Q_f exactly in every case.

Overlapping scans (--min-hit). Aligned scans of one surface lie a registration error apart, so
with the filter's 1e-5 limit rays from one scan hit the other's copy of the surface: the bunny's
mean ao per scan is 0.19-0.51 with --min-hit 0, 0.88-0.90 with the default `auto` (4 median
triangle edges = 3.1 mm; one scan alone: 0.91). AO does not depend on scale, so --min-hit D
hands the filter the mesh scaled by 1e-5 / D, which moves its limit to D metres.

Meshes from range scans. A scan's own faces are used as they are. Otherwise its grid (Stanford
`range_grid`, or per-vertex row/col) is triangulated: two triangles per 2x2 block of four
points (shorter diagonal), one per block of three; triangles with an edge above
--max-edge-factor (4) median edges are dropped (depth jumps), with edges measured relative to
range for a sensor at the origin, in metres for orthographic sensors (`comment sensor ortho`,
Cyberware data: looking along local -z); each is wound to face its sensor, since the filter
only casts rays in front of a face. A point in no triangle takes the value of the nearest
triangulated point of its scan within 4 grid cells, else 1 (both counted). Non-finite vertices
get 1. Exit status: 0 ok, 1 selftest failed, 2 bad input (one line
`compare_pymeshlab: error: FILE: what is wrong`, nothing written).
"""

import time

T_START = time.perf_counter()

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import struct  # noqa: E402
import sys  # noqa: E402
import xml.etree.ElementTree as ET  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

# pymeshlab's Qt needs a platform; without a display only "offscreen" works.
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

PROG = "compare_pymeshlab"
FILTER = "compute_scalar_ambient_occlusion"
DEFAULT_DIRS = 64
EDGE_FACTOR = 4.0
FILL_CELLS = 4
# Largest grid (cells) triangulated: its cell table takes 8 bytes a cell.
MAX_GRID_CELLS = 1 << 28
# Columns of the row appended with --csv. The sweep's CSV shares this list.
CSV_COLUMNS = ("label", "estimator", "dirs", "wall_s", "filter_s", "points")
ALIGN_EXTENSIONS = (".conf", ".mlp", ".json")
RIGID_TOLERANCE = 1e-3
OUTPUT_SUFFIX = ".pymeshlab.ply"
# The filter ignores hits nearer than this (scene units, fixed in MeshLab's Embree adaptor).
FILTER_TNEAR = 1e-5
# --min-hit auto: this many median triangle edges.
MIN_HIT_EDGES = 4.0
REPORT_NAME = "pymeshlab.json"
ROW_COL_NAMES = (("row", "col"), ("row_index", "column_index"), ("rowIndex", "columnIndex"))


class Failure(Exception):
    """Bad input or a failed step: `where` (a file or scan) and what is wrong."""

    def __init__(self, where, what):
        super().__init__(f"{where}: {what}")


# --------------------------------------------------------------------------------------------
# PLY

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class PlyProperty:
    """One property: a scalar (`count_type` None) or a list."""

    def __init__(self, name, dtype, count_type=None):
        self.name, self.dtype, self.count_type = name, dtype, count_type


class PlyElement:
    """One element: name, row count, properties, and after reading its data:
    `scalars[name]` = array, `lists[name]` = (counts, flat items)."""

    def __init__(self, name, count):
        self.name, self.count, self.props = name, count, []
        self.scalars, self.lists = {}, {}


class Ply:
    """The parts of a PLY file this script needs."""

    def __init__(self, path):
        self.path = Path(path)
        self.format = None
        self.comments, self.obj_info, self.elements = [], [], []

    def element(self, name):
        return next((e for e in self.elements if e.name == name), None)


def read_ply(path):
    """Reads a PLY file (ascii, binary little or big endian)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise Failure(path, e.strerror or str(e)) from None
    ply = Ply(path)
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise Failure(path, "not a PLY file (no 'ply' magic or no 'end_header')")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    header = data[:end].decode("latin-1").replace("\r", "").split("\n")
    for lineno, line in enumerate(header, 1):
        tok = line.split()
        if not tok or tok[0] == "ply":
            continue

        def bad(what, lineno=lineno):
            return Failure(path, f"header line {lineno}: {what}")
        key = tok[0]
        if key == "format":
            if len(tok) < 2 or tok[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise bad(f"unknown format '{' '.join(tok[1:])}'")
            ply.format = tok[1]
        elif key == "comment":
            ply.comments.append(line.split(None, 1)[1] if len(tok) > 1 else "")
        elif key == "obj_info":
            ply.obj_info.append(line.split(None, 1)[1] if len(tok) > 1 else "")
        elif key == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise bad(f"bad element line '{line.strip()}'")
            ply.elements.append(PlyElement(tok[1], int(tok[2])))
        elif key == "property":
            if not ply.elements:
                raise bad("property before any element")
            if len(tok) == 5 and tok[1] == "list":
                if tok[2] not in PLY_TYPES or tok[3] not in PLY_TYPES:
                    raise bad(f"unknown property type in '{line.strip()}'")
                prop = PlyProperty(tok[4], PLY_TYPES[tok[3]], PLY_TYPES[tok[2]])
            elif len(tok) == 3 and tok[1] in PLY_TYPES:
                prop = PlyProperty(tok[2], PLY_TYPES[tok[1]])
            else:
                raise bad(f"bad property line '{line.strip()}'")
            ply.elements[-1].props.append(prop)
        else:
            raise bad(f"unknown keyword '{key}'")
    if ply.format is None:
        raise Failure(path, "no format line in the header")
    if ply.format == "ascii":
        _read_ascii(ply, data[body_start:])
    else:
        endian = "<" if ply.format == "binary_little_endian" else ">"
        pos = body_start
        for el in ply.elements:
            pos = _read_binary_element(ply, el, data, pos, endian)
    return ply


def _read_binary_element(ply, el, buf, pos, endian):
    """Decodes one binary element starting at byte `pos`; returns the position after it."""
    n = el.count
    if not any(p.count_type for p in el.props):
        dt = np.dtype([(p.name, endian + p.dtype) for p in el.props])
        if pos + dt.itemsize * n > len(buf):
            raise Failure(ply.path, f"element '{el.name}': the body ends before row {n}")
        rows = np.frombuffer(buf, dt, n, pos)
        for p in el.props:
            el.scalars[p.name] = rows[p.name]
        return pos + dt.itemsize * n
    if n == 0:
        for p in el.props:
            if p.count_type:
                el.lists[p.name] = (np.zeros(0, np.int64), np.zeros(0, p.dtype))
            else:
                el.scalars[p.name] = np.zeros(0, p.dtype)
        return pos
    # Fast path: every list has the count of the first row (triangle faces).
    fields, q = [], pos
    for i, p in enumerate(el.props):
        if p.count_type:
            csz = np.dtype(p.count_type).itemsize
            if q + csz > len(buf):
                break
            c = int(np.frombuffer(buf, endian + p.count_type, 1, q)[0])
            fields.append((f"c{i}", endian + p.count_type))
            fields.append((f"v{i}", endian + p.dtype, (c,)))
            q += csz + c * np.dtype(p.dtype).itemsize
        else:
            fields.append((f"v{i}", endian + p.dtype))
            q += np.dtype(p.dtype).itemsize
    else:
        dt = np.dtype(fields)
        if pos + dt.itemsize * n <= len(buf):
            rows = np.frombuffer(buf, dt, n, pos)
            fixed = all(
                np.all(rows[f"c{i}"] == dt[f"v{i}"].shape[0])
                for i, p in enumerate(el.props) if p.count_type
            )
            if fixed:
                for i, p in enumerate(el.props):
                    if p.count_type:
                        items = rows[f"v{i}"]
                        counts = np.full(n, items.shape[1], np.int64)
                        el.lists[p.name] = (counts, items.reshape(-1).astype(p.dtype))
                    else:
                        el.scalars[p.name] = rows[f"v{i}"].astype(p.dtype)
                return pos + dt.itemsize * n
    # General path: one pass for the byte offsets, then a vectorised gather.
    offs = {p.name: [0] * n for p in el.props}
    cnts = {p.name: [0] * n for p in el.props if p.count_type}
    plan = []
    for p in el.props:
        size = np.dtype(p.dtype).itemsize
        if p.count_type:
            cfmt = struct.Struct(endian + np.dtype(p.count_type).char)
            plan.append((offs[p.name], cnts[p.name], cfmt, size))
        else:
            plan.append((offs[p.name], None, None, size))
    total = len(buf)
    try:
        for r in range(n):
            for off, cnt, cfmt, size in plan:
                if cnt is None:
                    off[r] = pos
                    pos += size
                else:
                    c = cfmt.unpack_from(buf, pos)[0]
                    pos += cfmt.size
                    off[r], cnt[r] = pos, c
                    pos += c * size
    except struct.error:
        raise Failure(ply.path, f"element '{el.name}': the body ends at row {r}") from None
    if pos > total:
        raise Failure(ply.path, f"element '{el.name}': the body ends before row {n}")
    raw = np.frombuffer(buf, np.uint8)
    for p in el.props:
        size = np.dtype(p.dtype).itemsize
        dt = np.dtype(endian + p.dtype)
        off = np.asarray(offs[p.name], np.int64)
        if p.count_type:
            counts = np.asarray(cnts[p.name], np.int64)
            if np.any(counts < 0):
                raise Failure(ply.path, f"element '{el.name}': negative list count")
            first = np.repeat(np.cumsum(counts) - counts, counts)
            starts = np.repeat(off, counts) + (np.arange(int(counts.sum())) - first) * size
            items = raw[starts[:, None] + np.arange(size)].copy().view(dt).reshape(-1)
            el.lists[p.name] = (counts, items.astype(p.dtype))
        else:
            vals = raw[off[:, None] + np.arange(size)].copy().view(dt).reshape(-1)
            el.scalars[p.name] = vals.astype(p.dtype)
    return pos


def _read_ascii(ply, body):
    """Decodes an ascii body."""
    tok = body.split()
    at = 0
    for el in ply.elements:
        n = el.count
        if not any(p.count_type for p in el.props):
            k = len(el.props)
            if at + n * k > len(tok):
                raise Failure(ply.path, f"element '{el.name}': the body ends before row {n}")
            try:
                vals = np.array(tok[at:at + n * k], dtype=np.float64).reshape(n, k)
            except ValueError:
                raise Failure(ply.path, f"element '{el.name}': a value is not a number") from None
            for j, p in enumerate(el.props):
                el.scalars[p.name] = vals[:, j].astype(p.dtype)
            at += n * k
            continue
        cols = {p.name: [] for p in el.props}
        counts = {p.name: [] for p in el.props if p.count_type}
        try:
            for _ in range(n):
                for p in el.props:
                    if p.count_type:
                        c = int(tok[at])
                        cols[p.name].extend(float(t) for t in tok[at + 1:at + 1 + c])
                        counts[p.name].append(c)
                        at += 1 + c
                    else:
                        cols[p.name].append(float(tok[at]))
                        at += 1
        except (IndexError, ValueError):
            raise Failure(ply.path, f"element '{el.name}': bad or missing value") from None
        for p in el.props:
            vals = np.asarray(cols[p.name], np.float64).astype(p.dtype)
            if p.count_type:
                el.lists[p.name] = (np.asarray(counts[p.name], np.int64), vals)
            else:
                el.scalars[p.name] = vals


def write_ao_ply(path, ply, ao, comment):
    """Writes `x y z` of `ply`'s vertices (their own types) and `float ao`, binary LE."""
    vert = ply.element("vertex")
    types = {p.name: p.dtype for p in vert.props}
    names = {"f4": "float", "f8": "double", "i1": "char", "u1": "uchar", "i2": "short",
             "u2": "ushort", "i4": "int", "u4": "uint"}
    dt = np.dtype([(c, "<" + types[c]) for c in "xyz"] + [("ao", "<f4")])
    rows = np.empty(vert.count, dt)
    for c in "xyz":
        rows[c] = vert.scalars[c]
    rows["ao"] = ao
    head = ["ply", "format binary_little_endian 1.0", f"comment {comment}",
            f"element vertex {vert.count}"]
    head += [f"property {names[types[c]]} {c}" for c in "xyz"]
    head += ["property float ao", "end_header"]
    write_atomic(path, ("\n".join(head) + "\n").encode("ascii") + rows.tobytes())


def write_atomic(path, payload):
    """Writes bytes to a hidden temporary file beside `path`, syncs, then renames it over."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise Failure(path, e.strerror or str(e)) from None


# --------------------------------------------------------------------------------------------
# Alignment (same formats and conventions as mvao's src/io/align.rs)

def quat_matrix(x, y, z, w):
    """Rotation matrix of a unit quaternion (scalar last)."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def check_rigid(m, path, what):
    """Rejects non-rigid poses like mvao and returns the pose with an orthonormal rotation."""
    if not np.all(np.isfinite(m)):
        raise Failure(path, f"pose of '{what}' has a non-finite entry")
    if np.max(np.abs(m[3] - [0, 0, 0, 1])) > 1e-9:
        raise Failure(path, f"pose of '{what}' has a projective bottom row")
    r = m[:3, :3]
    det = np.linalg.det(r)
    if det < 0:
        raise Failure(path, f"pose of '{what}' is a reflection (determinant {det:.6f})")
    dev = np.max(np.abs(r.T @ r - np.eye(3)))
    if not (dev <= RIGID_TOLERANCE and det > 0):
        raise Failure(path, f"pose of '{what}' has scale or shear (max |R^T R - I| = {dev:.3e})")
    u, _, vt = np.linalg.svd(r)
    out = m.copy()
    out[:3, :3] = u @ vt
    return out


def read_alignment(path):
    """Returns [(name as written, 4x4 local -> world)] from a .conf, .mlp or .json file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise Failure(path, e.strerror or str(e)) from None
    ext = path.suffix.lower()
    entries = []
    if ext == ".conf":
        for lineno, line in enumerate(text.splitlines(), 1):
            tok = line.split()
            if not tok or tok[0] != "bmesh":
                continue
            if len(tok) != 9:
                raise Failure(path, f"line {lineno}: a bmesh line needs a file name and 7 numbers")
            try:
                v = [float(t) for t in tok[2:]]
            except ValueError:
                raise Failure(path, f"line {lineno}: not a number") from None
            q = np.array(v[3:7])
            qn = np.linalg.norm(q)
            if not np.isfinite(qn) or qn < 1e-6:
                raise Failure(path, f"line {lineno}: the quaternion of '{tok[1]}' "
                                    "is not a rotation")
            # scanalyze convention, as mvao: world = R(q)^T p + t.
            m = np.eye(4)
            m[:3, :3] = quat_matrix(*(q / qn)).T
            m[:3, 3] = v[0:3]
            entries.append((tok[1], check_rigid(m, path, tok[1])))
    elif ext == ".mlp":
        try:
            root = ET.fromstring(text)
        except ET.ParseError as e:
            raise Failure(path, f"not a MeshLab project: {e}") from None
        for mesh in root.iter():
            if mesh.tag.split("}")[-1] != "MLMesh":
                continue
            name = (mesh.get("filename") or "").strip() or (mesh.get("label") or "").strip()
            if not name:
                raise Failure(path, "an MLMesh has neither a filename nor a label")
            mat = next((c for c in mesh if c.tag.split("}")[-1] == "MLMatrix44"), None)
            if mat is None:
                raise Failure(path, f"mesh '{name}' has no MLMatrix44")
            entries.append((name, _matrix16(path, name, (mat.text or "").split())))
    elif ext == ".json":
        try:
            pairs = json.loads(text, object_pairs_hook=lambda kv: kv)
        except ValueError as e:
            raise Failure(path, f"expected a JSON object of 16-number matrices: {e}") from None
        if not isinstance(pairs, list):
            raise Failure(path, "expected a JSON object of 16-number matrices")
        for name, vals in pairs:
            if not isinstance(vals, list):
                raise Failure(path, f"matrix of '{name}': expected an array of 16 numbers")
            entries.append((name, _matrix16(path, name, vals)))
    else:
        raise Failure(path, "unknown alignment format (expected a .conf, .mlp or .json file)")
    if not entries:
        raise Failure(path, "the alignment file names no scans")
    return entries


def _matrix16(path, name, vals):
    """A row-major 4x4 pose from 16 numbers, checked rigid."""
    if len(vals) != 16:
        raise Failure(path, f"matrix of '{name}': expected 16 numbers, found {len(vals)}")
    try:
        m = np.array([float(v) for v in vals], np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise Failure(path, f"matrix of '{name}': not all entries are numbers") from None
    return check_rigid(m, path, name)


def find_alignment_beside(scans):
    """The one alignment file in the scans' directories, None if there is none."""
    found = []
    for d in dict.fromkeys(s.parent for s in scans):
        try:
            items = sorted(d.iterdir())
        except OSError as e:
            raise Failure(d, e.strerror or str(e)) from None
        found += [p for p in items
                  if p.suffix.lower() in ALIGN_EXTENSIONS and p.is_file()
                  and not p.name.startswith(".") and p.name not in ("report.json", REPORT_NAME)]
    if len(found) > 1:
        raise Failure("alignment", "several alignment files beside the scans ("
                      + ", ".join(map(str, found)) + "); choose one with --align")
    return found[0] if found else None


def poses_for_scans(align_path, entries, scans):
    """One pose per scan: matched by file name, or by resolved path where names repeat."""
    names = [n.replace("\\", "/").rstrip("/").split("/")[-1] for n, _ in entries]
    norm = ["/".join(c for c in n.replace("\\", "/").split("/") if c not in ("", "."))
            for n, _ in entries]
    for i, k in enumerate(norm):
        if k in norm[:i]:
            raise Failure(align_path, f"'{entries[i][0]}' is named more than once")
    scan_names = [s.name for s in scans]
    owner, poses = [None] * len(entries), []
    for s in scans:
        ambiguous = names.count(s.name) > 1 or scan_names.count(s.name) > 1
        if ambiguous:
            key = os.path.realpath(s)
            hit = next((i for i, (n, _) in enumerate(entries)
                        if os.path.realpath(align_path.parent / n.replace("\\", "/")) == key), None)
        else:
            hit = names.index(s.name) if s.name in names else None
        if hit is None:
            raise Failure(align_path, f"scan '{s}' is not in the alignment file")
        if owner[hit] is not None:
            raise Failure(align_path, f"scans '{owner[hit]}' and '{s}' both match "
                                      f"'{entries[hit][0]}'")
        owner[hit] = s
        poses.append(entries[hit][1])
    unused = [f"'{entries[i][0]}'" for i, o in enumerate(owner) if o is None]
    if unused:
        raise Failure(align_path, ", ".join(unused) + " named in the alignment file but not given")
    return poses


# --------------------------------------------------------------------------------------------
# Scans → triangles

class ScanMesh:
    """One input scan: file, vertices (as read, local f64), pose, triangles (scan indices)."""

    def __init__(self, path):
        self.path = path
        self.stem = path.name[:-len(path.suffix)] if path.suffix else path.name
        self.ply = read_ply(path)
        vert = self.ply.element("vertex")
        if vert is None:
            raise Failure(path, "no vertex element")
        for c in "xyz":
            if c not in vert.scalars:
                raise Failure(path, f"vertex element has no '{c}' coordinate")
        self.local = np.stack([vert.scalars[c].astype(np.float64) for c in "xyz"], 1)
        self.finite = np.all(np.isfinite(self.local), 1)
        self.pose = np.eye(4)
        self.sensor = sensor_kind(self.ply)
        self.faces = None        # triangles, scan vertex indices
        self.source = None       # "faces" or "grid"
        self.grid = None         # (rows, cols, row per vertex, col per vertex) or None

    @property
    def n(self):
        return self.local.shape[0]


def sensor_kind(ply):
    """'ortho' (looking along local -z) or 'origin' (sensor at the local origin)."""
    for c in ply.comments:
        t = c.split()
        if len(t) >= 2 and t[0] == "sensor":
            return "ortho" if t[1] in ("ortho", "orthographic") else "origin"
    for o in ply.obj_info:
        t = o.split()
        if len(t) >= 2 and t[0] == "is_cyberware_data" and t[1] == "1":
            return "ortho"
    return "origin"


def grid_of(scan):
    """The native grid (rows, cols, row, col; -1 where a vertex has no cell) or None."""
    ply, n = scan.ply, scan.n
    rg = ply.element("range_grid")
    if rg is not None and "vertex_indices" in rg.lists:
        info = {}
        for o in ply.obj_info:
            t = o.split()
            if len(t) >= 2:
                info[t[0]] = t[1]
        try:
            cols, rows = int(info["num_cols"]), int(info["num_rows"])
        except (KeyError, ValueError):
            cols = rows = -1
        counts, items = rg.lists["vertex_indices"]
        if rows * cols == rg.count and rows > 0:
            items = items.astype(np.int64)
            if np.any((items < 0) | (items >= n)):
                raise Failure(scan.path, "range_grid names a vertex that does not exist")
            cell = np.repeat(np.arange(rg.count), counts)
            row = np.full(n, -1, np.int64)
            col = np.full(n, -1, np.int64)
            row[items], col[items] = cell // cols, cell % cols
            return rows, cols, row, col
    vert = ply.element("vertex")
    for rn, cn in ROW_COL_NAMES:
        if rn in vert.scalars and cn in vert.scalars:
            r = vert.scalars[rn].astype(np.float64)
            c = vert.scalars[cn].astype(np.float64)
            ok = np.isfinite(r) & np.isfinite(c) & (r >= 0) & (c >= 0) & (r < 1e7) & (c < 1e7)
            ok &= (r == np.round(r)) & (c == np.round(c))
            if n == 0 or not np.all(ok):
                return None
            row, col = r.astype(np.int64), c.astype(np.int64)
            return int(row.max()) + 1, int(col.max()) + 1, row, col
    return None


def faces_of(scan):
    """The scan's own polygons fanned into triangles, or None when it has no face element."""
    fe = scan.ply.element("face")
    if fe is None:
        return None
    lst = fe.lists.get("vertex_indices") or fe.lists.get("vertex_index")
    if lst is None:
        return None
    counts, items = lst
    items = items.astype(np.int64)
    if np.any((items < 0) | (items >= scan.n)):
        raise Failure(scan.path, "a face names a vertex that does not exist")
    first = np.cumsum(counts) - counts
    tris = []
    for k in range(1, int(counts.max(initial=0)) - 1):
        sel = counts >= k + 2
        f = first[sel]
        tris.append(np.stack([items[f], items[f + k], items[f + k + 1]], 1))
    if not tris:
        return np.zeros((0, 3), np.int64)
    t = np.concatenate(tris)
    return t[np.all(scan.finite[t], 1)]


def triangulate_grid(scan, factor):
    """Two triangles per full 2x2 block of cells, one per block with three points; drops
    triangles across depth jumps; winds every triangle to face the sensor."""
    rows, cols, row, col = scan.grid
    if rows * cols > MAX_GRID_CELLS:
        raise Failure(scan.path, f"grid of {rows} x {cols} cells is too large to triangulate")
    cell = np.full((rows, cols), -1, np.int64)
    have = np.nonzero(scan.finite & (row >= 0))[0][::-1]  # reversed: the first vertex wins
    cell[row[have], col[have]] = have
    a, b = cell[:-1, :-1].ravel(), cell[:-1, 1:].ravel()
    c, d = cell[1:, :-1].ravel(), cell[1:, 1:].ravel()
    p = scan.local
    va, vb, vc, vd = a >= 0, b >= 0, c >= 0, d >= 0
    full = va & vb & vc & vd

    def dist(i, j):
        return np.linalg.norm(p[i] - p[j], axis=1)
    fa, fb, fc, fd = a[full], b[full], c[full], d[full]
    ad_short = dist(fa, fd) <= dist(fb, fc)
    tris = [
        np.stack([fa, fc, fd], 1)[ad_short], np.stack([fa, fd, fb], 1)[ad_short],
        np.stack([fa, fc, fb], 1)[~ad_short], np.stack([fb, fc, fd], 1)[~ad_short],
    ]
    three = (va.astype(int) + vb + vc + vd) == 3
    for miss, keep in ((va, (b, d, c)), (vb, (a, c, d)), (vc, (a, d, b)), (vd, (a, c, b))):
        sel = three & ~miss
        tris.append(np.stack([k[sel] for k in keep], 1))
    t = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
    if len(t) == 0:
        return t
    p0, p1, p2 = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    edges = np.stack([np.linalg.norm(p1 - p0, axis=1), np.linalg.norm(p2 - p1, axis=1),
                      np.linalg.norm(p0 - p2, axis=1)], 1)
    centre = (p0 + p1 + p2) / 3.0
    if scan.sensor == "ortho":
        scale, toward = edges, np.broadcast_to([0.0, 0.0, 1.0], centre.shape)
    else:
        rng = np.linalg.norm(centre, axis=1)
        scale = edges / np.maximum(rng, 1e-12)[:, None]
        toward = -centre
    longest = scale.max(1)
    median = float(np.median(scale)) if scale.size else 0.0
    normal = np.cross(p1 - p0, p2 - p0)
    area2 = np.linalg.norm(normal, axis=1)
    keep = (longest <= factor * median) & (area2 > 0) & np.isfinite(area2)
    flip = np.einsum("ij,ij->i", normal, toward) < 0
    t = t.copy()
    t[flip, 1], t[flip, 2] = t[flip, 2], t[flip, 1].copy()
    return t[keep]


def fill_from_grid(scan, values, covered):
    """Gives uncovered gridded points the value of the nearest covered point (3-D distance)
    within FILL_CELLS grid cells. Returns the mask of points that found one."""
    rows, cols, row, col = scan.grid
    need = np.nonzero(~covered & scan.finite & (row >= 0))[0]
    found = np.zeros(scan.n, bool)
    if need.size == 0:
        return found
    cell = np.full((rows, cols), -1, np.int64)
    ok = np.nonzero(covered)[0]
    cell[row[ok], col[ok]] = ok
    best_d = np.full(need.size, np.inf)
    best_i = np.full(need.size, -1, np.int64)
    r0, c0 = row[need], col[need]
    for dr in range(-FILL_CELLS, FILL_CELLS + 1):
        for dc in range(-FILL_CELLS, FILL_CELLS + 1):
            r, c = r0 + dr, c0 + dc
            inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
            j = np.full(need.size, -1, np.int64)
            j[inside] = cell[r[inside], c[inside]]
            hit = j >= 0
            d = np.full(need.size, np.inf)
            d[hit] = np.linalg.norm(scan.local[j[hit]] - scan.local[need[hit]], axis=1)
            better = d < best_d
            best_d[better], best_i[better] = d[better], j[better]
    got = best_i >= 0
    values[need[got]] = values[best_i[got]]
    found[need[got]] = True
    return found


# --------------------------------------------------------------------------------------------
# The filter and the mapping

def fibonacci_directions(n):
    """The filter's directions: vcg::GenNormal<float>::Fibonacci(n), in float32 like it."""
    i = np.arange(n, dtype=np.float32)
    big_phi = np.float32(math.sqrt(5) * 0.5 + 0.5)
    ratio = i / big_phi
    phi = (np.float32(2.0 * math.pi) * (ratio - np.floor(ratio))).astype(np.float32)
    cos_t = (np.float32(1) - (np.float32(2) * i + np.float32(1)) / np.float32(n)).astype(np.float32)
    sin_t = np.sqrt(np.clip(np.float32(1) - cos_t * cos_t, 0, 1)).astype(np.float32)
    return np.stack([np.cos(phi) * sin_t, np.sin(phi) * sin_t, cos_t], 1).astype(np.float64)


def open_sum(normals, dirs, chunk=1 << 16):
    """D_f = sum over directions of max(n_f . w, 0): the quality of a fully open face."""
    out = np.empty(len(normals))
    for s in range(0, len(normals), chunk):
        out[s:s + chunk] = np.maximum(normals[s:s + chunk] @ dirs.T, 0.0).sum(1)
    return out


def run_filter(verts, faces, dirs, min_hit=None):
    """Runs the filter on one mesh. Returns face quality, face normals, vertex quality and the
    (wall, CPU of all threads) time of the filter call alone. `min_hit` (scene units) scales
    the mesh so that the filter's fixed near limit FILTER_TNEAR falls at that distance; the AO
    values do not depend on scale."""
    import pymeshlab

    scale = FILTER_TNEAR / min_hit if min_hit else 1.0
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(verts * scale, np.float64),
                               face_matrix=np.ascontiguousarray(faces, np.int32)))
    if "rays" not in ms.filter_parameter_values(FILTER):
        raise Failure(FILTER, f"pymeshlab {_pymeshlab_version()} has no CPU (Embree) version of "
                              "this filter; install the one in scripts/requirements-compare.txt")
    t0, c0 = time.perf_counter(), time.process_time()
    ms.apply_filter(FILTER, rays=int(dirs))
    filter_s, filter_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    m = ms.current_mesh()
    if m.face_number() != len(faces) or m.vertex_number() != len(verts):
        raise Failure(FILTER, f"the mesh changed size ({len(verts)} vertices, {len(faces)} faces "
                              f"in; {m.vertex_number()}, {m.face_number()} out)")
    return (np.asarray(m.face_scalar_array(), np.float64),
            np.asarray(m.face_normal_matrix(), np.float64),
            np.asarray(m.vertex_scalar_array(), np.float64), (filter_s, filter_cpu_s))


def map_to_unit(verts, faces, face_q, face_n, vertex_q, dirs):
    """Per-vertex a in [0,1] (see the module docstring), the mask of vertices that a face with
    a defined value touches, and checks of the mapping."""
    dsum = open_sum(face_n, fibonacci_directions(dirs))
    valid = dsum > 1e-9
    a_f = np.zeros(len(faces))
    a_f[valid] = np.clip(face_q[valid] / dsum[valid], 0.0, 1.0)
    p = verts[faces]
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    n = len(verts)
    w_all = np.bincount(faces.ravel(), np.repeat(area2, 3), n)
    q_all = np.bincount(faces.ravel(), np.repeat(area2 * face_q, 3), n)
    w = np.bincount(faces.ravel(), np.repeat(area2 * valid, 3), n)
    s = np.bincount(faces.ravel(), np.repeat(area2 * valid * a_f, 3), n)
    covered = w > 0
    a = np.ones(n)
    a[covered] = np.clip(s[covered] / w[covered], 0.0, 1.0)
    touched = w_all > 0
    # The filter's own vertex step against the area-weighted mean of its face values.
    own = q_all[touched] / w_all[touched]
    rel = np.abs(own - vertex_q[touched]) / np.maximum(np.abs(vertex_q[touched]), 1.0)
    ratio = dsum / (dirs / 4.0)
    checks = {
        "open_face_value_over_dirs_div_4": [float(ratio.min()), float(ratio.max())],
        "faces_without_directions": int((~valid).sum()),
        "vertex_step_max_rel_diff": float(rel.max()) if rel.size else 0.0,
    }
    return a, covered, checks


# --------------------------------------------------------------------------------------------
# Main run

def parse_args(argv):
    ap = argparse.ArgumentParser(
        prog="compare_pymeshlab.py",
        description="Run pymeshlab's ambient occlusion on scans and write mvao-style AO files.")
    ap.add_argument("scans", nargs="*", type=Path, help="input PLY scans")
    ap.add_argument("--align", type=Path, help="alignment file (.conf, .mlp, .json)")
    ap.add_argument("-o", "--output", type=Path, help="output directory")
    ap.add_argument("--dirs", type=int, default=DEFAULT_DIRS,
                    help=f"directions on the sphere (the filter's 'rays'; default {DEFAULT_DIRS})")
    ap.add_argument("--max-edge-factor", type=float, default=EDGE_FACTOR,
                    help=f"drop grid triangles with an edge above this many median edges "
                         f"(default {EDGE_FACTOR:g})")
    ap.add_argument("--min-hit", default="auto", metavar="D",
                    help="ignore hits nearer than D metres: 'auto' (default) = "
                         f"{MIN_HIT_EDGES:g} x the median triangle edge; 0 = the filter's own "
                         f"{FILTER_TNEAR:g} scene units")
    ap.add_argument("--csv", type=Path, help="append a timing row to this CSV")
    ap.add_argument("--label", help="the row's label (with --csv)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    ap.add_argument("--selftest", action="store_true",
                    help="check the mapping on a plane, boxes and walls; print JSON")
    args = ap.parse_args(argv)
    if args.dirs < 1:
        ap.error("--dirs must be at least 1")
    if args.min_hit != "auto":
        try:
            args.min_hit = float(args.min_hit)
        except ValueError:
            ap.error("--min-hit must be 'auto' or a number of metres")
        if not (args.min_hit >= 0 and math.isfinite(args.min_hit)):
            ap.error("--min-hit must be 'auto' or a number of metres >= 0")
    if not (args.max_edge_factor > 0 and math.isfinite(args.max_edge_factor)):
        ap.error("--max-edge-factor must be a positive number")
    if not args.selftest:
        if not args.scans:
            ap.error("no input scans")
        if args.output is None:
            ap.error("-o OUTDIR is required")
        if (args.csv is None) != (args.label is None):
            ap.error("--csv and --label go together")
    return args


def planned_outputs(args):
    """The output paths, checked: distinct stems, no input overwritten, none existing unless
    --force."""
    stems = {}
    for s in args.scans:
        stem = s.name[:-len(s.suffix)] if s.suffix else s.name
        if stem in stems:
            raise Failure(s, f"has the same stem as {stems[stem]} (their outputs would collide)")
        stems[stem] = s
    outputs = [args.output / f"{stem}{OUTPUT_SUFFIX}" for stem in stems]
    for o in outputs + [args.output / REPORT_NAME]:
        if not o.exists():
            continue
        if any(s.exists() and os.path.samefile(o, s) for s in args.scans):
            raise Failure(o, "the output would overwrite an input")
        if not args.force:
            raise Failure(o, "exists (add --force to overwrite)")
    if args.csv is not None:
        csv_header(args.csv)
    return outputs


def load_scans(args):
    """Reads every scan and its pose; returns the scans and the alignment file used."""
    scans = [ScanMesh(s) for s in args.scans]
    align_path = args.align or find_alignment_beside(args.scans)
    if align_path is not None:
        poses = poses_for_scans(Path(align_path), read_alignment(align_path), args.scans)
        for sc, pose in zip(scans, poses):
            sc.pose = pose
    elif len(scans) > 1:
        print(f"{PROG}: warning: no alignment file: all scans taken as already aligned",
              file=sys.stderr)
    return scans, align_path


def build_mesh(scans, edge_factor):
    """Triangles of every scan, joined into one mesh in world coordinates minus the centre of
    the scene's bounding box. Returns vertices, faces and each scan's first vertex index."""
    for sc in scans:
        f = faces_of(sc)
        sc.grid = grid_of(sc)
        if f is not None and len(f):
            sc.faces, sc.source = f, "faces"
        elif sc.grid is not None:
            sc.faces, sc.source = triangulate_grid(sc, edge_factor), "grid"
        else:
            raise Failure(sc.path, "has neither faces nor a range grid: nothing to "
                                   "triangulate for the filter")
    world = np.concatenate([sc.local @ sc.pose[:3, :3].T + sc.pose[:3, 3] for sc in scans])
    finite = np.concatenate([sc.finite for sc in scans])
    if not finite.any():
        raise Failure("scans", "no finite vertex")
    centre = (world[finite].min(0) + world[finite].max(0)) * 0.5
    verts = world - centre
    verts[~finite] = 0.0  # no face uses them
    first = np.cumsum([0] + [sc.n for sc in scans])[:-1]
    faces = np.concatenate([sc.faces + b for sc, b in zip(scans, first)])
    if len(faces) == 0:
        raise Failure("scans", "no triangle could be built from the scans")
    return verts, faces, first


def choose_min_hit(setting, verts, faces):
    """The near limit in metres (None = the filter's own): 'auto' = MIN_HIT_EDGES median
    triangle edges, 0 = the filter's own, else the number given."""
    if setting == "auto":
        p = verts[faces]
        setting = MIN_HIT_EDGES * float(np.median(np.linalg.norm(p - np.roll(p, 1, 1), axis=2)))
    return setting if setting > 0 else None


def scan_values(sc, a, covered):
    """One scan's output values from the mesh's: uncovered points take a grid neighbour's
    value or 1, non-finite points 1. Returns the values and their counts."""
    ao = a.copy()
    uncovered = ~covered & sc.finite
    filled = np.zeros(sc.n, bool)
    if sc.grid is not None and uncovered.any():
        filled = fill_from_grid(sc, ao, covered)
    fallback = uncovered & ~filled
    ao[fallback | ~sc.finite] = 1.0
    ao = np.clip(np.nan_to_num(ao, nan=1.0), 0.0, 1.0).astype(np.float32)
    return ao, {"untriangulated": int(uncovered.sum()), "filled_from_neighbour":
                int(filled.sum()), "fallback_open": int(fallback.sum()),
                "nonfinite": int((~sc.finite).sum())}


def run(args):
    """The comparison run: read, mesh, filter, map, write."""
    outputs = planned_outputs(args)
    t = time.perf_counter()
    scans, align_path = load_scans(args)
    read_s = time.perf_counter() - t

    t = time.perf_counter()
    verts, faces, first = build_mesh(scans, args.max_edge_factor)
    min_hit = choose_min_hit(args.min_hit, verts, faces)
    mesh_s = time.perf_counter() - t

    t = time.perf_counter()
    face_q, face_n, vertex_q, times = run_filter(verts, faces, args.dirs, min_hit)
    filter_s, filter_cpu_s = times
    run_s = time.perf_counter() - t

    t = time.perf_counter()
    a, covered, checks = map_to_unit(verts, faces, face_q, face_n, vertex_q, args.dirs)
    values, infos = [], []
    totals = dict.fromkeys(("untriangulated", "filled_from_neighbour", "fallback_open",
                            "nonfinite"), 0)
    for sc, b, out in zip(scans, first, outputs):
        ao, counts = scan_values(sc, a[b:b + sc.n], covered[b:b + sc.n])
        values.append(ao)
        for k, v in counts.items():
            totals[k] += v
        infos.append({"name": sc.stem, "input": str(sc.path), "output": str(out),
                      "vertices": sc.n, "triangles": int(len(sc.faces)),
                      "mesh_from": sc.source, "sensor": sc.sensor, **counts,
                      "ao_mean": float(ao.mean()) if sc.n else None})
    map_s = time.perf_counter() - t

    t = time.perf_counter()
    try:
        args.output.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise Failure(args.output, e.strerror or str(e)) from None
    comment = (f"ao from pymeshlab {FILTER}, {args.dirs} directions, "
               f"mapped to [0,1] (1 = open) by compare_pymeshlab.py")
    for sc, out, ao in zip(scans, outputs, values):
        write_ao_ply(out, sc.ply, ao, comment)
    write_s = time.perf_counter() - t
    wall_s = time.perf_counter() - T_START

    points = int(sum(sc.n for sc in scans))
    report = {
        "tool": "pymeshlab",
        "pymeshlab_version": _pymeshlab_version(),
        "filter": FILTER,
        "dirs": args.dirs,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "alignment": str(align_path) if align_path is not None else None,
        "mapping": "a_v = area-weighted mean over faces of clamp(Q_f / D_f, 0, 1), "
                   "D_f = sum over the filter's directions of max(n_f.w, 0); "
                   "1 = open, t_max = infinity",
        "mapping_checks": checks,
        # The quantity, in the keys `mvao eval` reads to refuse a reference of another one.
        "parameters": {"ssao": {"tmax": "inf", "falloff": "none"}},
        "max_edge_factor": args.max_edge_factor,
        "min_hit_m": min_hit or FILTER_TNEAR,
        "min_hit_from": (f"auto: {MIN_HIT_EDGES:g} x median edge" if args.min_hit == "auto"
                         else "--min-hit" if min_hit else "the filter's own near limit"),
        "points": points,
        "triangles": int(len(faces)),
        **totals,
        "timings_s": {"read": read_s, "mesh": mesh_s, "filter": filter_s,
                      "filter_cpu": filter_cpu_s,
                      "filter_with_setup": run_s, "map": map_s, "write": write_s,
                      "wall": wall_s},
        "scans": infos,
    }
    write_atomic(args.output / REPORT_NAME, (json.dumps(report, indent=1) + "\n").encode())
    if args.csv is not None:
        append_csv(args.csv, {"label": args.label, "estimator": "pymeshlab", "dirs": args.dirs,
                              "wall_s": f"{wall_s:.4f}", "filter_s": f"{filter_s:.4f}",
                              "points": points})
    print(f"{PROG}: {len(scans)} scans, {points} points, {len(faces)} triangles, "
          f"{args.dirs} directions, hits nearer than {min_hit or FILTER_TNEAR:.3g} m ignored: "
          f"filter {filter_s:.2f} s, wall {wall_s:.2f} s; {totals['untriangulated']} points "
          f"in no triangle ({totals['filled_from_neighbour']} took a neighbour's value, "
          f"{totals['fallback_open']} set to 1); outputs in {args.output}")


def csv_header(path):
    """The header `append_csv` will write under: the file's own, or CSV_COLUMNS for a new or
    empty file. Checked before any work so that a bad CSV fails the run early."""
    path = Path(path)
    try:
        if not path.exists() or path.stat().st_size == 0:
            return None
        with open(path, newline="") as f:
            header = next(csv.reader(f), None)
    except OSError as e:
        raise Failure(path, e.strerror or str(e)) from None
    missing = [c for c in CSV_COLUMNS if c not in (header or [])]
    if missing:
        raise Failure(path, "the CSV header lacks " + ", ".join(missing))
    return header


def append_csv(path, row):
    """Appends `row` under the file's header (written from CSV_COLUMNS when the file is new)."""
    header = csv_header(path)
    try:
        with open(path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=header or list(CSV_COLUMNS), restval="")
            if header is None:
                w.writeheader()
            w.writerow(row)
    except OSError as e:
        raise Failure(path, e.strerror or str(e)) from None


def _pymeshlab_version():
    try:
        from importlib.metadata import version
        return version("pymeshlab")
    except Exception:  # noqa: BLE001 - the version is informative only
        return None


# --------------------------------------------------------------------------------------------
# Self-test: analytic scenes

def _quad(origin, u, v, nu, nv):
    """A grid of (nu x nv) cells spanning origin + [0,1]u + [0,1]v; triangles wound so their
    normal is u x v."""
    s = np.linspace(0.0, 1.0, nu + 1)
    t = np.linspace(0.0, 1.0, nv + 1)
    ss, tt = np.meshgrid(s, t, indexing="ij")
    verts = (np.asarray(origin, float) + ss.reshape(-1, 1) * np.asarray(u, float)
             + tt.reshape(-1, 1) * np.asarray(v, float))
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return verts, faces


def _scene(quads):
    """Concatenates quads; returns vertices, faces and the vertex offset of each quad."""
    verts, faces, offs, n = [], [], [], 0
    for q in quads:
        v, f = _quad(*q)
        verts.append(v)
        faces.append(f + n)
        offs.append(n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces), offs


def _vertex_at(verts, p):
    return int(np.argmin(np.linalg.norm(verts - np.asarray(p, float), axis=1)))


def selftest(dirs):
    """Runs the filter on analytic scenes and compares the mapped values with their AO."""
    half = 0.5 / math.sqrt(1.25)
    open_box_exact = 4.0 / (2.0 * math.pi) * 2.0 * half * math.atan(half)
    floor = ((-1, -1, 0), (2, 0, 0), (0, 2, 0), 20, 20)         # normal +z
    cases = []
    # Open plane: a square, normal +z.
    cases.append(("open_plane", [floor], (0, 0, 0), 1.0))
    # Closed unit box, floor normal inward (+z); the other faces only block rays.
    box = [((0, 0, 0), (1, 0, 0), (0, 1, 0), 10, 10), ((0, 0, 1), (0, 1, 0), (1, 0, 0), 10, 10),
           ((0, 0, 0), (0, 0, 1), (1, 0, 0), 10, 10), ((0, 1, 0), (1, 0, 0), (0, 0, 1), 10, 10),
           ((0, 0, 0), (0, 1, 0), (0, 0, 1), 10, 10), ((1, 0, 0), (0, 0, 1), (0, 1, 0), 10, 10)]
    cases.append(("closed_box_floor_centre", box, (0.5, 0.5, 0), 0.0))
    cases.append(("open_box_floor_centre", [q for k, q in enumerate(box) if k != 1],
                  (0.5, 0.5, 0), open_box_exact))
    # Floor y >= 0 at the foot of a wall in the plane y = 0 (20 x 10 m).
    wall_floor = ((-10, 0, 0), (20, 0, 0), (0, 10, 0), 40, 20)
    wall = ((-10, 0, 0), (0, 0, 10), (20, 0, 0), 20, 40)
    cases.append(("wall_foot", [wall_floor, wall], (0, 0, 0), 0.5))
    # Floor x, y >= 0 in the corner of two walls (x = 0 and y = 0).
    corner_floor = ((0, 0, 0), (10, 0, 0), (0, 10, 0), 20, 20)
    wall_x = ((0, 0, 0), (0, 10, 0), (0, 0, 10), 20, 20)
    wall_y = ((0, 0, 0), (0, 0, 10), (10, 0, 0), 20, 20)
    cases.append(("wall_wall_floor_corner", [corner_floor, wall_x, wall_y], (0, 0, 0), 0.25))

    # The same open box handed to the filter at 1/100 scale (--min-hit 1 mm): AO must not move.
    open_box = next(c for c in cases if c[0] == "open_box_floor_centre")
    cases.append(("open_box_floor_centre_scaled",) + open_box[1:])

    # The plane and the closed box are exact. The rest are approximations by N directions (a
    # few cannot resolve a quarter hemisphere) of scenes with finite walls (exact values about
    # 0.01 above the ideal ones); they are checked from 64 directions on.
    tol = 0.6 / math.sqrt(dirs) + 0.02
    results, ok = [], True
    for name, quads, point, expected in cases:
        verts, faces, offs = _scene(quads)
        min_hit = 1e-3 if name.endswith("_scaled") else None
        face_q, face_n, vertex_q, _ = run_filter(verts, faces, dirs, min_hit)
        a, _, checks = map_to_unit(verts, faces, face_q, face_n, vertex_q, dirs)
        # The query vertex on the first quad (the floor), not a coincident wall vertex.
        n_floor = offs[1] if len(offs) > 1 else len(verts)
        vi = _vertex_at(verts[:n_floor], point)
        # Every vertex of an open plane is open: take the darkest.
        value = float(a[:n_floor].min() if name == "open_plane" else a[vi])
        exact = expected in (0.0, 1.0)
        checked = exact or dirs >= 64
        passed = bool(abs(value - expected) <= (1e-4 if exact else tol)) or not checked
        if name.endswith("_scaled"):
            unscaled = next(r["a"] for r in results if r["case"] == name[:-len("_scaled")])
            passed &= abs(value - unscaled) <= 1e-3
        ok &= passed
        results.append({"case": name, "raw_vertex_quality": float(vertex_q[vi]), "a": value,
                        "expected": expected, "tolerance": 1e-4 if exact else tol,
                        "checked": checked, "passed": passed,
                        "vertex_step_max_rel_diff": checks["vertex_step_max_rel_diff"]})
    rng = np.random.default_rng(0)
    n = rng.normal(size=(2000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = open_sum(n, fibonacci_directions(dirs)) / (dirs / 4.0)
    out = {"filter": FILTER, "pymeshlab_version": _pymeshlab_version(), "dirs": dirs,
           "cases": results, "open_sum_over_dirs_div_4": [float(d.min()), float(d.max())],
           "passed": bool(ok)}
    print(json.dumps(out, indent=1))
    return 0 if ok else 1


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        import pymeshlab
        del pymeshlab  # imported here only to fail early with a clear message
    except ImportError as e:
        print(f"{PROG}: error: pymeshlab is not installed ({e}); "
              f"pip install -r scripts/requirements-compare.txt", file=sys.stderr)
        return 2
    try:
        if args.selftest:
            return selftest(args.dirs)
        run(args)
    except Failure as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
