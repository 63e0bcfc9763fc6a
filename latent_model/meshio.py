"""The user's own mesh: import, normalisation into the model frame, and export back.

The model works in anny's frame: metres, Z up, the character faces -Y, +X is the character's
left, origin near the pelvis. A user's file may be Y-up centimetres (a Maya export), Z-up
millimetres, etc. `load_mesh` detects the up axis and the units from the bounding box (a human
is 1.4-2.1 m tall; flags override the guess), reads the character as facing the up axis's
convention (Y-up: +Z, Z-up: -Y) or the axis it is told (a character made facing +X, as Unreal
exports them; `latent_model/facing.py` finds it with the model), places the body like the model's characters,
and stores the mapping so `export_mesh` can write the result back in the user's frame and
units, with the input's vertex order and faces (an OBJ input is rewritten line by line, so
groups, UVs and materials survive).

Mapping (stored in `Frame`): model = scale * R @ user + offset, user = R.T @ (model - offset) / scale.

Coincident vertices (seams of glTF/OBJ exports, STL triangle soup) are welded for the model;
`UserMesh.weld_inverse` maps the welded vertices back to the file's vertices on export.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import get_args

import numpy as np

from latent_model.atomic import atomic_write_bytes
from latent_model.errors import UserFacingError
from latent_model.types import Facing, Units, UpAxis

FORMATS = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")  # what load_mesh reads
EXPORT_FORMATS = (".obj", ".ply", ".stl", ".glb", ".off")  # what export_mesh writes (the one list)
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
HUMAN_HEIGHT_M = (1.4, 2.1)  # what the detection expects
SANE_HEIGHT_M = (0.5, 3.0)  # outside this after unit conversion the scale is absurd
# Placement of the model's characters, fitted on corpus v4's 112 training neutrals (every training rest): the
# surface's area centroid at x = 0.000 (std 7 mm), y = -0.047 m (std 12 mm; the bounding box's centre moves with
# the arms, -0.13 in bind, -0.05 in a T-pose), feet at z = -0.261 * stature - 0.371 m (residual std 46 mm). The
# bounding-box rule before (centre y -0.13, feet -0.505 * stature) stood validation characters exported in
# centimetres 27 mm (y) and 94 mm (z) off, some out of distribution (docs/history.md).
_ANNY_CENTROID_XY = (0.0, -0.047)
_ANNY_FEET_Z = (-0.261, -0.371)  # feet z = a * stature + b (metres)
_FEET_Z_SPREAD = 0.15  # 3 residual stds: feet this far from the fit are still a placed character's
# A posed body's bounding box moves with its limbs (a bent hip or knee: up to 30 cm), its vertices' median x and y
# do not (measured on the corpus: within 5 cm of its neutral's; neutral medians y -0.18...-0.12): a mesh whose
# median lies here and whose lowest point is a human's feet in the model frame is already placed.
_ANNY_MEDIAN_Y = -0.14
_PLACED_MEDIAN_MM = (80.0, 100.0)  # x, y tolerance of that median

# Y-up (character facing +Z, left hand at +X) -> Z-up facing -Y: rotate +90 deg about X.
_R_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_R_Z_UP = np.eye(3)
_AXES = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
         "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}
CONVENTIONAL_FACING = {"y": "+z", "z": "-y"}  # the axis a file of each up axis is read as facing by default


class MeshError(UserFacingError, ValueError):
    """A mesh file the user gave cannot be used; the message names the file and the fix."""


@dataclass(frozen=True)
class Frame:
    """model = scale * R @ user + offset (R a rotation (3, 3), scale from user units to metres)."""

    up: str  # "y" | "z" (of the user's file)
    units: str  # "m" | "cm" | "mm"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    scale: float = 1.0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    facing: str = ""  # the file axis the character faces ("+x"); "" for the up axis's convention

    def to_model(self, user: np.ndarray) -> np.ndarray:
        """(V, 3) user coordinates -> (V, 3) float32 model coordinates."""
        return (self.scale * (np.asarray(user, np.float64) @ self.R.T) + self.offset).astype(np.float32)

    def to_user(self, model: np.ndarray) -> np.ndarray:
        """(V, 3) model coordinates -> (V, 3) float64 user coordinates (inverse of to_model)."""
        return ((np.asarray(model, np.float64) - self.offset) / self.scale) @ self.R

    def describe(self) -> str:
        facing = f", facing {self.facing.upper()}" if self.facing else ""
        return f"{self.units}, {self.up.upper()}-up{facing}"

    def to_dict(self) -> dict:
        return {"up": self.up, "units": self.units, "R": self.R.tolist(), "scale": self.scale,
                "offset": self.offset.tolist(), "facing": self.facing}


IDENTITY_FRAME = Frame("z", "m")


@dataclass
class UserMesh:
    """A mesh in the model frame plus what is needed to write results back into its file's frame.

    vertices (V, 3) float32 model frame (welded), faces (F, 3) int64 into `vertices`,
    sdf_faces: faces of the closed shells used for the SDF latent (small inner shells such as
    eyeballs dropped), weld_inverse (N,) file vertex -> welded vertex, file_faces (F', 3) the
    file's triangles (file vertex indices)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    sdf_faces: np.ndarray
    frame: Frame
    weld_inverse: np.ndarray
    file_faces: np.ndarray
    source_path: Path | None = None
    source_text: str | None = None  # the OBJ text, for a faithful rewrite on export
    # its latent mean (Z,) as read (SDF sample seed 0), when `facing.face_front` has encoded it: prepare need not again
    mu: np.ndarray | None = None

    @property
    def n_file_vertices(self) -> int:
        return len(self.weld_inverse)

    def summary(self) -> str:
        h = float(np.ptp(self.vertices[:, 2]))
        return (f"{self.name}: {self.n_file_vertices} vertices ({len(self.vertices)} welded), {len(self.faces)} triangles, "
                f"file frame {self.frame.describe()}, stature {h:.2f} m")


# ----------------------------------------------------------------------------- reading
def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """(N, 3) vertices in file order, (F, 3) triangles (polygons fanned), and the text."""
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise MeshError(f"{path}: cannot read the file ({e.strerror or e})") from None
    verts: list[str] = []
    faces: list[list[int]] = []
    n = 0
    for line in text.splitlines():
        if line.startswith("v "):
            verts.append(line[2:])
            n += 1
        elif line.startswith("f "):
            idx = []
            for tok in line[2:].split():
                try:
                    k = int(tok.split("/", 1)[0])
                except ValueError:
                    raise MeshError(f"{path}: malformed face line {line.strip()!r}; re-export the OBJ") from None
                idx.append(k - 1 if k > 0 else n + k)
            for j in range(1, len(idx) - 1):
                faces.append([idx[0], idx[j], idx[j + 1]])
    try:
        v = np.array([s.split()[:3] for s in verts], dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise MeshError(f"{path}: malformed vertex line (expected 'v x y z'); re-export the OBJ") from None
    return v, np.array(faces, dtype=np.int64).reshape(-1, 3), text


def _read_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        obj = trimesh.load(str(path), process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises many kinds; all mean "unreadable"
        raise MeshError(f"{path}: cannot read it as a {path.suffix[1:].upper()} mesh ({type(e).__name__}: {e}); "
                        f"check the file or re-export it") from None
    if isinstance(obj, trimesh.Scene):
        parts = []
        for node in obj.graph.nodes_geometry:
            transform, name = obj.graph[node]
            g = obj.geometry[name]
            if isinstance(g, trimesh.Trimesh):
                g = g.copy()
                g.apply_transform(transform)
                parts.append(g)
            elif hasattr(g, "vertices"):
                parts.append(trimesh.Trimesh(np.asarray(g.vertices), np.zeros((0, 3), np.int64), process=False))
        if not parts:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        vs, fs, off = [], [], 0
        for g in parts:
            vs.append(np.asarray(g.vertices, np.float64))
            fs.append(np.asarray(g.faces, np.int64).reshape(-1, 3) + off)
            off += len(g.vertices)
        return np.concatenate(vs), np.concatenate(fs)
    v = np.asarray(getattr(obj, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    f = np.asarray(getattr(obj, "faces", np.zeros((0, 3))), np.int64)
    return v, f.reshape(-1, 3) if f.size else np.zeros((0, 3), np.int64)


def read_file(path: str | Path) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(N, 3) float64 vertices and (F, 3) int64 triangles in the file's own frame and order,
    and the OBJ text (None for other formats). Raises MeshError with a clear message."""
    path = Path(path)
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    if path.is_dir():
        raise MeshError(f"{path}: is a directory, not a mesh file")
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise MeshError(f"{path}: unsupported format {suffix or '(no extension)'}; use one of {', '.join(FORMATS)}")
    if path.stat().st_size == 0:
        raise MeshError(f"{path}: the file is empty")
    text = None
    if suffix == ".obj":
        v, f, text = _read_obj(path)
    else:
        v, f = _read_trimesh(path)
    return v, f, text


# ----------------------------------------------------------------------------- checks, frame
def _check(path: str, v: np.ndarray, f: np.ndarray) -> None:
    if len(v) == 0:
        raise MeshError(f"{path}: the mesh is empty (no vertices)")
    if not np.isfinite(v).all():
        bad = int((~np.isfinite(v).all(axis=1)).sum())
        raise MeshError(f"{path}: {bad} vertices have NaN or infinite coordinates; fix or re-export the mesh")
    if len(f) == 0:
        raise MeshError(f"{path}: {len(v)} vertices but no faces: a point cloud cannot be used; "
                        f"export the mesh with its triangles (faces)")
    if f.min() < 0 or f.max() >= len(v):
        raise MeshError(f"{path}: faces reference vertices that do not exist (index {int(f.max())} of {len(v)}); "
                        f"the file is corrupt, re-export it")
    if len(v) < 4:
        raise MeshError(f"{path}: only {len(v)} vertices; a character mesh is needed")


def _yaw_facing_front(forward: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation about Z that turns the horizontal unit vector `forward` to the model's front, -Y."""
    angle = np.arctan2(forward[0], -forward[1])  # forward's angle from -Y, towards +X
    c, s = np.cos(-angle), np.sin(-angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def horizontal_axes(up: str) -> tuple[str, ...]:
    """The file axes a character standing along `up` ("y" | "z") may face, its convention first."""
    return (CONVENTIONAL_FACING[up], *(a for a in _AXES if a[1] != up and a != CONVENTIONAL_FACING[up]))


def _axis_name(v: np.ndarray) -> str:
    k = int(np.argmax(np.abs(v)))
    return ("+" if v[k] > 0 else "-") + "xyz"[k]


def area_centroid(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(3,) the area-weighted centroid of a surface (V, 3), (F, 3): whatever its tessellation."""
    tri = np.asarray(vertices, np.float64)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return (tri.mean(axis=1) * area[:, None]).sum(axis=0) / max(float(area.sum()), 1e-30)


def detect_frame(vertices: np.ndarray, up: UpAxis = "auto", units: Units = "auto", name: str = "mesh",
                 placement: str = "auto", facing: Facing = "auto", faces: np.ndarray | None = None) -> Frame:
    """The mapping from a file's frame into the model's.

    up: "auto" picks the larger of the Y and Z bounding-box extents (a standing human is taller
    than deep); units: "auto" picks m/cm/mm so that the height is nearest a human's 1.4-2.1 m.
    facing: the file axis the character faces; "auto": the up axis's convention (Y-up: +Z, Z-up: -Y).
    faces: the mesh's triangles, when known: its placement then reads the surface's area centroid (else the
    vertices' median).
    placement: "auto" re-centres like the model's characters unless the mesh is already Z-up
    metres, facing -Y and placed like them, in their neutral or in a pose (then it is kept), "keep" never moves
    it, "centre" always does.
    Raises MeshError for an absurd scale or a bad flag."""
    v = np.asarray(vertices, np.float64)
    ext = np.ptp(v, axis=0)
    if up not in get_args(UpAxis):
        raise MeshError(f"up axis {up!r}: use {', '.join(get_args(UpAxis))}")
    if units not in get_args(Units):
        raise MeshError(f"units {units!r}: use {', '.join(get_args(Units))}")
    if placement not in ("auto", "keep", "centre"):
        raise MeshError(f"placement {placement!r}: use auto, keep or centre")
    if facing not in get_args(Facing):
        raise MeshError(f"facing {facing!r}: use {', '.join(get_args(Facing))}")
    up_axis = up if up != "auto" else ("y" if ext[1] > ext[2] else "z")
    R = _R_Y_UP if up_axis == "y" else _R_Z_UP
    forward = R @ np.array(_AXES[CONVENTIONAL_FACING[up_axis] if facing == "auto" else facing])
    if abs(forward[2]) > 0.5:
        raise MeshError(f"{name}: facing {facing.upper()} is the up axis ({up_axis.upper()}); a standing character "
                        f"faces a horizontal axis: pass --facing {' or '.join(horizontal_axes(up_axis))}")
    turned = not np.allclose(forward, [0.0, -1.0, 0.0])
    if turned:
        R = _yaw_facing_front(forward) @ R
    facing_name = _axis_name(R.T @ np.array([0.0, -1.0, 0.0])) if turned else ""
    height = float(ext[1] if up_axis == "y" else ext[2])
    if not height > 0:
        raise MeshError(f"{name}: the mesh is flat along its up axis ({up_axis.upper()}); pass --up if the guess is wrong")
    if units == "auto":
        target = np.sqrt(HUMAN_HEIGHT_M[0] * HUMAN_HEIGHT_M[1])
        unit = min(UNITS, key=lambda u: abs(np.log(height * UNITS[u] / target)))
    else:
        unit = units
    scale = UNITS[unit]
    h_m = height * scale
    if not SANE_HEIGHT_M[0] <= h_m <= SANE_HEIGHT_M[1]:
        raise MeshError(f"{name}: absurd scale: the mesh is {height:.4g} units tall along {up_axis.upper()}, "
                        f"{h_m:.4g} m in {unit}; the model expects a human of {HUMAN_HEIGHT_M[0]}-{HUMAN_HEIGHT_M[1]} m. "
                        f"Pass --units m|cm|mm (and --up y|z) if the guess is wrong, or rescale the mesh")
    m = scale * (v @ R.T)
    lo = m.min(axis=0)
    med = np.median(m, axis=0)
    if faces is not None and len(faces):
        centre, target = area_centroid(m, faces), _ANNY_CENTROID_XY
    else:  # no faces: the vertices' median, which the vertices' density pulls (anny's dense head and hands)
        centre, target = med, (0.0, _ANNY_MEDIAN_Y)
    feet = _ANNY_FEET_Z[0] * h_m + _ANNY_FEET_Z[1]
    shift = np.array([target[0] - centre[0], target[1] - centre[1], feet - lo[2]])
    feet_range = (_ANNY_FEET_Z[0] * HUMAN_HEIGHT_M[1] + _ANNY_FEET_Z[1] - _FEET_Z_SPREAD,
                  _ANNY_FEET_Z[0] * HUMAN_HEIGHT_M[0] + _ANNY_FEET_Z[1] + _FEET_Z_SPREAD)
    posed_in_place = (abs(med[0]) * 1000 < _PLACED_MEDIAN_MM[0] and abs(med[1] - _ANNY_MEDIAN_Y) * 1000 < _PLACED_MEDIAN_MM[1]
                      and feet_range[0] <= lo[2] <= feet_range[1])
    if placement == "keep" or (placement == "auto" and up_axis == "z" and unit == "m"
                               and (np.all(np.abs(shift) < np.array([0.05, 0.1, _FEET_Z_SPREAD])) or posed_in_place)):
        shift = np.zeros(3)
    return Frame(up_axis, unit, R.copy(), scale, shift, facing_name)


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge exactly coincident vertices: (welded (W, 3), faces into welded, inverse (N,))."""
    uniq, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(uniq) == len(vertices):
        return vertices, faces, np.arange(len(vertices))
    # keep the welded vertices in first-occurrence order (stable, close to the file's order)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    inv = rank[inverse]
    return vertices[first[order]], inv[faces], inv


def sdf_shell_faces(vertices: np.ndarray, faces: np.ndarray, min_area_fraction: float = 0.02) -> np.ndarray:
    """Faces of the shells that make up the body for the SDF: connected components holding at
    least `min_area_fraction` of the surface (eyeballs, tongue and other small inner shells are
    dropped; a body split into several large parts keeps them all, the winding number unites them)."""
    import scipy.sparse
    import scipy.sparse.csgraph

    n = len(vertices)
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    adj = scipy.sparse.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    _, labels = scipy.sparse.csgraph.connected_components(adj, directed=False)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    comp = labels[faces[:, 0]]
    comp_area = np.bincount(comp, weights=area)
    keep = comp_area >= min_area_fraction * comp_area.sum()
    return np.ascontiguousarray(faces[keep[comp]])


def from_arrays(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh", up: UpAxis = "auto",
                units: Units = "auto", placement: str = "auto", source_path: Path | None = None,
                source_text: str | None = None, frame: Frame | None = None, facing: Facing = "auto") -> UserMesh:
    """A UserMesh from arrays in some user frame (see `detect_frame`; `frame` given: that one, as for the
    posed mesh of an example pair, which must stay where its neutral is)."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3) if np.size(faces) else np.zeros((0, 3), np.int64)
    _check(name, v, f)
    if frame is None:
        frame = detect_frame(v, up, units, name, placement, facing, f)
    wv, wf, inv = weld(v, f)
    keep = (wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 0] != wf[:, 2])
    wf = wf[keep]
    if len(wf) == 0:
        raise MeshError(f"{name}: every triangle is degenerate (zero area); the file is broken, re-export it")
    mv = frame.to_model(wv)
    return UserMesh(name, mv, wf, sdf_shell_faces(mv.astype(np.float64), wf), frame, inv, f, source_path, source_text)


def load_mesh(path: str | Path, up: UpAxis = "auto", units: Units = "auto", placement: str = "auto",
              frame: Frame | None = None, facing: Facing = "auto") -> UserMesh:
    """Read a mesh file (OBJ, PLY, STL, GLB/GLTF, OFF) and normalise it into the model frame (or `frame`)."""
    path = Path(path)
    v, f, text = read_file(path)
    return from_arrays(v, f, path.name, up, units, placement, path, text, frame, facing)


def load_example_pair(neutral: str | Path, posed: str | Path, up: UpAxis = "auto",
                      units: Units = "auto", facing: Facing = "auto") -> tuple[UserMesh, UserMesh]:
    """An example pair: a character's mesh and the same mesh deformed, both in the neutral's frame
    (the posed one's bounding box would move it). Raises MeshError unless they share one topology."""
    a = load_mesh(neutral, up, units, facing=facing)
    b = load_mesh(posed, frame=a.frame)
    if b.n_file_vertices != a.n_file_vertices or not np.array_equal(a.file_faces, b.file_faces):
        raise MeshError(f"{b.name} must be {a.name} deformed (the same vertices and triangles): it has "
                        f"{b.n_file_vertices} vertices and {len(b.file_faces)} triangles, {a.name} "
                        f"{a.n_file_vertices} and {len(a.file_faces)}. Export both from the same mesh")
    if not np.array_equal(a.weld_inverse, b.weld_inverse):
        # a deformation that makes welded vertices differ (or coincide): weld both the neutral's way
        b = UserMesh(b.name, a.frame.to_model(read_file(Path(posed))[0][_first_of_welded(a.weld_inverse)]),
                     a.faces, a.sdf_faces, a.frame, a.weld_inverse, a.file_faces, b.source_path, b.source_text)
    return a, b


def _first_of_welded(inverse: np.ndarray) -> np.ndarray:
    """(W,) a file vertex of each welded vertex."""
    first = np.full(int(inverse.max()) + 1, -1)
    first[inverse[::-1]] = np.arange(len(inverse))[::-1]
    return first


def from_identity(vertices: np.ndarray, faces: np.ndarray, name: str, sdf_faces: np.ndarray | None = None) -> UserMesh:
    """A corpus identity's mesh (already in the model frame: identity mapping, no welding, so
    vertex i stays vertex i and predictions compare with the rig's ground truth vertex by vertex)."""
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)
    _check(name, v, f)
    if sdf_faces is None:
        from latent_model.corpus.sdf import body_component_faces

        sdf_faces = body_component_faces(v.astype(np.float64), f)
    return UserMesh(name, v, f, np.asarray(sdf_faces, np.int64), IDENTITY_FRAME, np.arange(len(v)), f)


# ----------------------------------------------------------------------------- writing
_FACE_NORMAL_REF = re.compile(r"(\S+?)/(\S*?)/\S+")


def _rewrite_obj(text: str, user_vertices: np.ndarray) -> str:
    """The input OBJ with its `v` lines replaced (same order), stale `vn` normals dropped."""
    out: list[str] = []
    k = 0
    for line in text.splitlines():
        if line.startswith("v "):
            x, y, z = user_vertices[k]
            extra = line[2:].split()[3:]  # vertex colours, if any
            out.append(f"v {x:.6f} {y:.6f} {z:.6f}" + ("".join(" " + e for e in extra)))
            k += 1
        elif line.startswith("vn "):
            continue
        elif line.startswith("f "):
            toks = []
            for t in line[2:].split():
                m = _FACE_NORMAL_REF.fullmatch(t)
                toks.append((m.group(1) + ("/" + m.group(2) if m.group(2) else "")) if m else t)
            out.append("f " + " ".join(toks))
        else:
            out.append(line)
    return "\n".join(out) + "\n"


def export_mesh(mesh: UserMesh, model_vertices: np.ndarray, path: str | Path) -> Path:
    """Write predicted vertices (W, 3) (model frame, welded order) in the file's frame, units and
    vertex order. OBJ from an OBJ input keeps every non-vertex line; other formats are written by
    trimesh. Atomic: an existing file is replaced only by a complete one."""
    import trimesh

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_FORMATS:
        raise MeshError(f"{path}: cannot export {suffix or '(no extension)'}; use one of {', '.join(EXPORT_FORMATS)}")
    mv = np.asarray(model_vertices)
    if mv.shape != mesh.vertices.shape:
        raise MeshError(f"{path}: prediction has shape {mv.shape}, the mesh {mesh.vertices.shape}")
    if not np.isfinite(mv).all():
        raise MeshError(f"{path}: the prediction has NaN/inf vertices; nothing written")
    user = mesh.frame.to_user(mv)[mesh.weld_inverse]
    if suffix == ".obj" and mesh.source_text is not None:
        data = _rewrite_obj(mesh.source_text, user).encode()
    else:
        tm = trimesh.Trimesh(user, mesh.file_faces, process=False)
        data = trimesh.exchange.export.export_mesh(tm, None, file_type=suffix[1:])
        if isinstance(data, str):
            data = data.encode()
    if path.parent and not path.parent.exists():
        raise MeshError(f"{path}: the directory {path.parent} does not exist")
    atomic_write_bytes(path, data)
    return path
