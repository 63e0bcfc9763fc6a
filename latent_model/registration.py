"""Where anny's vertices lie on a mesh of another topology: anny's template stood like it and registered onto it.

What is indexed by anny's vertices (the corrective fields) reads a mesh through anny's topology. For a mesh of
another tessellation (decimated, remeshed, made elsewhere) anny's template is stood like it (the build and rest
angles whose skinned template lies nearest its surface, with the pose it is said to be in), then carried onto it
by a non-rigid ICP: closest points both ways, the displacements smoothed over the template by a graph Laplacian
that relaxes over the iterations. Then each anny vertex has a point on the mesh (`Correspondence.on_mesh`) and
each mesh vertex a point on the template (`Correspondence.to_mesh` carries a field over anny's vertices to it).
A similarity alone left 10-45 mm between two persons' regions: a crease read centimetres off (docs/history.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the build's anny phenotype sliders fitted (0..1, 0.5 the template's default) and their bounds; the rest angles'
PHENOTYPES = ("gender", "age", "muscle", "weight", "proportions", "height")
PHENOTYPE_BOUNDS = ((0.0, 1.0), (0.35, 1.0), (0.0, 1.0), (0.0, 1.0), (0.0, 1.0), (0.0, 1.0))
LOCAL_BOUNDS = ((-1.0, 1.0),) * 6
# and its local changes (-1..1, 0 the default): the limbs' lengths and the torso's depth, where a stylised build
# differs most (a fit without them put a stylised character's elbow 7 cm off)
LOCAL = ("measure-upperarm-length-incr", "measure-lowerarm-length-incr", "upperlegs-height-incr",
         "lowerlegs-height-incr", "torso-scale-depth-incr", "measure-neck-height-incr")
ANGLES = ("arms", "elbows", "legs", "spine")
ANGLE_BOUNDS = ((-60.0, 60.0), (-45.0, 60.0), (-15.0, 20.0), (-10.0, 30.0))
LANDMARKS = 0.2  # weight of the five extremities' squared distance (height units) beside the mean squared distance
STIFFNESS = (40.0, 15.0, 6.0, 2.0, 0.7)  # the Laplacian's weight, per stage of the non-rigid ICP
# a pose's region whose template vertices the registration carried farther than this (median, mm) from where the fit
# stood them was not stood like the mesh (validation, decimated characters, 36 reads: 4 of the 5 reads worse than no
# motion or within 0.05 of it settled 41-58 mm, the 5th 37 mm where anny's own topology reads -0.07 too; every read
# explaining more than 0.3 settled <= 34 mm)
SETTLE_LIMIT = 40.0
SAMPLE = 3000  # points of each mesh the fit's distance reads
FIT_EVALS = 1500  # the fit's distance evaluations at most (Powell; a stylised validation elbow: 600 left 14 mm, 2000 4 mm)


@dataclass
class Correspondence:
    """anny's template registered onto a mesh: for each anny vertex its point on the mesh (`faces` (Va,) of the
    mesh's triangles, `bary` (Va, 3)); for each mesh vertex its point on the registered template (`back_faces`
    (Vm,) of `anny_faces`, `back_bary` (Vm, 3)); `residual_mm` the median distance of the template's vertices from
    the mesh after registration, `settle_mm` how far it carried each of them from where the fit stood them."""

    faces: np.ndarray
    bary: np.ndarray
    back_faces: np.ndarray
    back_bary: np.ndarray
    anny_faces: np.ndarray
    residual_mm: float
    settle_mm: np.ndarray  # (Va,) how far the registration moved each template vertex from the fitted template

    def on_mesh(self, vertices: np.ndarray, mesh_faces: np.ndarray) -> np.ndarray:
        """(Va, 3) anny's vertices placed on the mesh `vertices` (Vm, 3) (its triangles `mesh_faces`)."""
        tri = np.asarray(vertices, np.float64)[np.asarray(mesh_faces)[self.faces]]  # (Va, 3, 3)
        return np.einsum("nk,nkj->nj", self.bary, tri)

    def settled(self, index: np.ndarray) -> float:
        """Median of `settle_mm` over anny vertices `index` (a region): how far the fit stood it from the mesh."""
        return float(np.median(self.settle_mm[np.asarray(index)]))

    def to_mesh(self, field: np.ndarray) -> np.ndarray:
        """(Vm, 3) a field over anny's vertices (Va, 3) read at each mesh vertex's point on the template."""
        tri = np.asarray(field, np.float64)[self.anny_faces[self.back_faces]]
        return np.einsum("nk,nkj->nj", self.back_bary, tri)


def _closest(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(face (N,), barycentric (N, 3), closest point (N, 3)) of each point on a triangle mesh."""
    import igl

    _, face, closest = igl.point_mesh_squared_distance(points, vertices, faces)
    tri = vertices[faces[face]]
    bary = igl.barycentric_coordinates(closest, tri[:, 0].copy(), tri[:, 1].copy(), tri[:, 2].copy())
    bary = np.clip(np.nan_to_num(bary, nan=1.0 / 3.0), 0.0, 1.0)  # a degenerate triangle: its centre
    total = bary.sum(axis=1, keepdims=True)
    return face.astype(np.int64), np.where(total > 0, bary / np.maximum(total, 1e-12), 1.0 / 3.0), closest


def _normalised(v: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(points standing on z = 0 centred in x, y, scaled to height 1; the height; the offset subtracted)."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    offset = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    height = float(hi[2] - lo[2]) or 1.0
    return (v - offset) / height, height, offset


class TemplateFitter:
    """anny's template skinned in a build, rest angles and a pose, fitted to a mesh (canonical frame: Z up, facing
    -Y, metres). A build's rest shape is anny's, linear between each slider's ends and its default (one anny call
    per end, once): a fit reads hundreds of builds."""

    def __init__(self, rig=None) -> None:
        from latent_model.corpus.rig import Rig
        from latent_model.surface import surface_features

        self.rig = rig or Rig()
        base = self.rig.base_rest
        self._base = (base.vertices, base.heads)
        self._ends = []  # per slider: its (low end, high end) offsets from the template, (vertices, heads) each
        for p in PHENOTYPES + LOCAL:
            ends = (({p: 0.0}, {}), ({p: 1.0}, {})) if p in PHENOTYPES else (({}, {p: -1.0}), ({}, {p: 1.0}))
            ends = [self.rig.rest(*e) for e in ends]
            self._ends.append(tuple((e.vertices - base.vertices, e.heads - base.heads) for e in ends))
        ext = surface_features(base.vertices, self.rig.faces).extremities
        self.extremities = np.array([ext[k] for k in sorted(ext)])

    def rest(self, build: np.ndarray):
        """The template's rest shape in a build (values of `PHENOTYPES` then `LOCAL`)."""
        from latent_model.corpus.rig import RestShape

        v, h = self._base[0].copy(), self._base[1].copy()
        defaults = [0.5] * len(PHENOTYPES) + [0.0] * len(LOCAL)
        for (low, high), x, d in zip(self._ends, build, defaults):
            dv, dh = high if x >= d else low
            a = abs(float(x) - d) / (1.0 - d) if x >= d else abs(float(x) - d) / (d - (0.0 if d else -1.0))
            v += a * dv
            h += a * dh
        return RestShape(v, h)

    def skinned(self, build: np.ndarray, angles: np.ndarray, pose: str | None, only: np.ndarray | None = None
                ) -> np.ndarray:
        """(Va, 3) the template in a build, rest angles (as `ANGLES`, degrees) and a pose (None: standing); `only`:
        those vertices (N,) alone, (N, 3)."""
        from latent_model.corpus.poses import get_pose
        from latent_model.corpus.rests import RestConfig

        rest = self.rest(build)
        base = RestConfig("fit", **dict(zip(ANGLES, map(float, angles)))).joints
        joints = get_pose(pose).joints if pose is not None else ()
        t = self.rig.bone_transforms(rest, joints, base)
        idx = np.arange(len(rest.vertices)) if only is None else only
        m = np.einsum("vk,vkij->vij", self.rig.weights[idx], t[self.rig.weight_bones[idx], :3, :])
        return np.einsum("vij,vj->vi", m[:, :, :3], rest.vertices[idx]) + m[:, :, 3]

    def fit(self, vertices: np.ndarray, faces: np.ndarray, pose: str | None = None, seed: int = 0) -> np.ndarray:
        """(Va, 3) the template standing nearest the mesh (`vertices` (Vm, 3), `faces`), in its place and size: the
        build and rest angles whose skinned template has the least mean squared distance to the mesh both ways
        plus `LANDMARKS` x that of the five extremities (`surface.surface_features`), heights normalised."""
        from scipy.optimize import linear_sum_assignment, minimize
        from scipy.spatial import cKDTree

        from latent_model.corpus.rests import REST_CONFIGS, TRAIN_RESTS
        from latent_model.surface import surface_features

        rng = np.random.default_rng(seed)
        v = np.asarray(vertices, np.float64)
        ext = surface_features(v, faces).extremities
        target, height, offset = _normalised(v)
        marks = target[[ext[k] for k in sorted(ext)]]
        target = target[rng.choice(len(target), min(SAMPLE, len(target)), replace=False)]
        tree = cKDTree(target)
        pick = np.concatenate([rng.choice(len(self.rig.weights), SAMPLE, replace=False), self.extremities])

        n_build = len(PHENOTYPES) + len(LOCAL)

        def cost(x: np.ndarray) -> float:
            t = _normalised(self.skinned(x[:n_build], x[n_build:], pose, pick))[0]
            there = tree.query(t[:SAMPLE])[0]
            back = cKDTree(t[:SAMPLE]).query(target)[0]
            # the extremities matched as a set: the surface names a hand raised above the head "head" (a raised arm's
            # fit pulled the template's head to the hand: 106 mm off, validation armsUp35 + shoulderRaiseLf)
            d = np.sum((t[SAMPLE:, None] - marks[None]) ** 2, axis=-1)  # (5, 5)
            return float(np.mean(there ** 2) + np.mean(back ** 2) + LANDMARKS * d[linear_sum_assignment(d)].sum())

        build = np.array([0.5] * len(PHENOTYPES) + [0.0] * len(LOCAL))
        starts = [np.concatenate([build, [getattr(REST_CONFIGS[r], a) for a in ANGLES]]) for r in TRAIN_RESTS]
        res = minimize(cost, min(starts, key=cost), method="Powell", bounds=PHENOTYPE_BOUNDS + LOCAL_BOUNDS + ANGLE_BOUNDS,
                       options={"xtol": 1e-2, "ftol": 1e-5, "maxfev": FIT_EVALS})
        fitted, _, _ = _normalised(self.skinned(res.x[:n_build], res.x[n_build:], pose))
        return fitted * height + offset


_FITTER: list = []  # this process's fitter (its anny rig is not picklable: kept out of `Transfer`)


def template_fitter() -> TemplateFitter:
    """This process's `TemplateFitter`, made on first use (anny's rig and 24 of its rest shapes, a few seconds)."""
    if not _FITTER:
        _FITTER.append(TemplateFitter())
    return _FITTER[0]


def _laplacian(faces: np.ndarray, n: int):
    import scipy.sparse as sp

    from latent_model.topology import mesh_edges

    e = mesh_edges(faces)
    a = sp.coo_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))),
                      shape=(n, n)).tocsr()
    a.data[:] = 1.0
    return sp.diags(np.asarray(a.sum(axis=1)).ravel()) - a


def register(template: np.ndarray, template_faces: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
             iterations: int = 3) -> np.ndarray:
    """(Va, 3) the template (Va, 3) carried onto the mesh (`vertices` (Vm, 3), `faces`) by a non-rigid ICP: each
    stage (`STIFFNESS`) moves every template vertex by the smoothed mean of its closest point on the mesh and the
    pull of the mesh vertices whose nearest template vertex it is (so limbs the template misses are reached)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu
    from scipy.spatial import cKDTree

    x = np.asarray(template, np.float64).copy()
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    n = len(x)
    lap = _laplacian(np.asarray(template_faces, np.int64), n)
    for stiffness in STIFFNESS:
        solve = splu((sp.eye(n) + stiffness * lap).tocsc())
        for _ in range(iterations):
            _, _, closest = _closest(x, v, f)
            pull = closest - x
            _, near = cKDTree(x).query(v)
            count = np.bincount(near, minlength=n)
            back = np.stack([np.bincount(near, weights=v[:, k] - x[near, k], minlength=n) for k in range(3)], axis=1)
            has = count > 0
            pull[has] = 0.5 * pull[has] + 0.5 * back[has] / count[has, None]
            x = x + np.stack([solve.solve(pull[:, k]) for k in range(3)], axis=1)
    return x


def correspond(fitter: TemplateFitter, vertices: np.ndarray, faces: np.ndarray, pose: str | None = None
               ) -> Correspondence:
    """anny's template fitted (`TemplateFitter.fit`) and registered (`register`) onto the mesh, both ways."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    anny_faces = fitter.rig.faces
    fitted = fitter.fit(v, f, pose)
    x = register(fitted, anny_faces, v, f)
    face, bary, closest = _closest(x, v, f)
    # each mesh vertex read on anny's vertices placed on the mesh (on its surface, unlike the template itself, which
    # can lie nearer another part where two touch: an arm at the side)
    back_face, back_bary, _ = _closest(v, closest, anny_faces)
    residual = float(np.median(np.linalg.norm(closest - x, axis=1))) * 1000.0
    settle = (np.linalg.norm(x - fitted, axis=1) * 1000.0).astype(np.float32)
    return Correspondence(face, bary, back_face, back_bary, np.asarray(anny_faces, np.int64), residual, settle)
