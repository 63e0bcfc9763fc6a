"""Which way a user's character faces, when its file does not say: the model's own judgement.

The model's characters face -Y with Z up. A file is read as facing its up axis's convention (Y-up: +Z, Z-up: -Y,
`meshio.detect_frame`), but a character made elsewhere may face another horizontal axis (Unreal exports face
+X). Read the wrong way round, its latent lies far from every training state: a validation character turned by
90 or 180 degrees lies 35-54 from them against the threshold of 11.6, and its elbow bend explains 0.43 to -0.73
instead of 0.88 (docs/history.md). Turned back it is itself again. So a mesh the bank finds out of distribution is
tried facing each other horizontal axis of its file and takes one that brings it within the threshold (the
nearest, if several, of those below); a mesh within it is never turned, and one that no facing brings within keeps
its reading (and its warning). The up axis is read from the bounding box, and the arms of a character facing
sideways in a Z-up file can span more than its height: unless the user named the up axis, the other one is tried.
A T-pose read backwards can lie within the threshold too (a test character: facing -X nearer than +X), so among
the readings within it those whose toes reach forward (`toes_ahead`: every corpus neutral's do, by 9-15 cm at
1.7 m) come first. And a character with its arms at its sides turned round lies within the threshold as read
(two validation characters: 6.5 and 5.8), and so does a posed source turned round (validation characters with a
bent knee, a bent spine, a raised arm: 4-32 turned round, against the posed threshold of 18.7; some nearer than as
read). So a mesh whose toes point clearly backwards (`toes_ahead`, the feet standing on the ground) is read facing
the other way when that reading is within the threshold too; and out of distribution, a neutral is only read
facing where its toes point ahead (a stylised character facing front, novel as it is, is not turned round because
its back reading happens to lie nearer). Only a neutral there: of a posed mesh, only those within the threshold.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from latent_model.meshio import Frame, UserMesh, detect_frame, horizontal_axes
from latent_model.types import PairKind

# at 1.7 m tall: a mesh whose toes point this far behind its ankles faces the other way (corpus neutrals: +9-15 cm)
TOES_BACK_M = 0.05
FOOT_DOWN = 0.01  # a foot whose lowest point stands this far (of the height) off the ground is lifted
FOOT_FLAT = 0.005  # a foot rests on its vertices this close (of the height) to its lowest point


def with_frame(mesh: UserMesh, frame: Frame) -> UserMesh:
    """The same file mesh read through another frame (its model vertices redone; the file's own untouched)."""
    user = mesh.frame.to_user(mesh.vertices)
    # read otherwise, it has another latent
    return dataclasses.replace(mesh, vertices=frame.to_model(user), frame=frame, mu=None)


def facing(mesh: UserMesh, axis: str, up: str | None = None) -> UserMesh:
    """The mesh read as facing the file axis `axis` ("+x"...) with up axis `up` (default: as read), placed like the
    model's characters."""
    user = mesh.frame.to_user(mesh.vertices)
    return with_frame(mesh, detect_frame(user, up or mesh.frame.up, mesh.frame.units, mesh.name, "auto", axis,
                                         mesh.faces))


def toes_ahead(vertices) -> float:
    """How far (m, along -Y) the feet of a standing mesh (V, 3; model frame) reach ahead of their ankles: for each
    foot on the ground (the lowest 12 % of the height split at its median x; the foot's lowest point within 1 % of
    the mesh's), its sole (its lowest 3 %) ahead of its ankle (5-10 % above its lowest point); their mean, each
    weighed by the vertices it rests on (within `FOOT_FLAT` of its lowest point). Positive when it faces -Y. Per
    foot on the ground, since a lifted leg hangs its foot behind or ahead of anything; weighed, since a hip flexed
    with the knee bent can hang its foot as low as the standing one's, toes down and back (to -0.15 against the
    standing foot's +0.14), resting on a tenth as many vertices: the largest of the feet read such a mesh turned
    round as facing front. hipFlexLf + kneeBentLf on the 184 shipped characters: +0.05 to +0.17, and turned round
    none above -0.05 (the largest of the feet: 74). Corpus neutrals +0.09 to +0.15 at 1.7 m, posed meshes 7 of
    36,282 below -0.05 (kneeling on both bent knees)."""
    v = np.asarray(vertices, np.float64)
    height = max(float(np.ptp(v[:, 2])), 1e-12)
    z = (v[:, 2] - v[:, 2].min()) / height
    low, zl = v[z < 0.12], z[z < 0.12]
    middle = np.median(low[:, 0]) if len(low) else 0.0
    ahead = []
    for side in (low[:, 0] < middle, low[:, 0] >= middle):
        foot, zf = low[side], zl[side]
        if len(foot) == 0 or zf.min() > FOOT_DOWN:
            continue  # a lifted foot says nothing of where the body faces
        sole = foot[zf < zf.min() + 0.03]
        ankle = foot[(zf > zf.min() + 0.05) & (zf < zf.min() + 0.10)]
        if len(sole) and len(ankle):
            rests = np.count_nonzero(zf < zf.min() + FOOT_FLAT)  # a flat sole's many vertices, a toe tip's few
            ahead.append((float(ankle[:, 1].mean() - sole[:, 1].mean()), rests))
    return float(np.average([a for a, _ in ahead], weights=[w for _, w in ahead])) if ahead else 0.0


def face_front(transfer, mesh: UserMesh, kind: PairKind = "neutral_to_pose", up_known: bool = False,
               progress=lambda text: None) -> UserMesh:
    """`mesh`, or the mesh read as facing the horizontal axis of its file (and standing along the other up axis,
    unless `up_known`) under which the model finds it within its out-of-distribution threshold for a source of pair
    kind `kind`, or a mesh turned round onto its toes (module docstring). Encodes the mesh once, and once per
    other reading only when it is out of distribution or its toes point back; a bank without a threshold
    leaves it as read. `progress(text)` is told before the others are tried. The mesh returned carries its latent
    (`UserMesh.mu`, seed 0) for `Transfer.prepare`."""
    bank = transfer.bank
    threshold = bank.threshold_for(kind)
    if threshold <= 0:
        return mesh

    def encoded(m: UserMesh) -> UserMesh:
        """The reading with its latent (encoded now unless it carries one)."""
        return m if m.mu is not None else dataclasses.replace(m, mu=transfer.encode(m.vertices, m.sdf_faces))

    def distance(m: UserMesh) -> float:
        return bank.distance_to_training(m.mu)

    read = mesh.frame.facing or horizontal_axes(mesh.frame.up)[0]
    forward = TOES_BACK_M * float(np.ptp(mesh.vertices[:, 2])) / 1.7  # toes this far ahead: a neutral's front
    mesh = encoded(mesh)
    if distance(mesh) <= threshold:
        if toes_ahead(mesh.vertices) > -forward:
            return mesh
        back = encoded(facing(mesh, ("-" if read[0] == "+" else "+") + read[1]))
        return back if distance(back) <= threshold and toes_ahead(back.vertices) > 0 else mesh
    progress(f"{mesh.name} read facing {read.upper()} lies far from the model's characters: trying the other facings")
    within = []
    ups = (mesh.frame.up,) if up_known else (mesh.frame.up, "y" if mesh.frame.up == "z" else "z")
    for up in ups:
        for axis in horizontal_axes(up):
            if (up, axis) == (mesh.frame.up, read):
                continue
            try:
                turned = facing(mesh, axis, up)
            except ValueError:  # standing along the other axis the mesh is no human's height: not this reading
                continue
            toes = toes_ahead(turned.vertices)
            if kind == "neutral_to_pose" and toes < forward:
                continue  # a neutral stands on its feet: a reading whose toes do not point ahead is not its front
            turned = encoded(turned)
            d = distance(turned)
            if d <= threshold:
                within.append((toes <= 0, d, len(within), turned))  # toes forward first
    return min(within)[-1] if within else mesh


def face_front_pair(transfer, neutral: UserMesh, posed: UserMesh, up_known: bool = False,
                    progress=lambda text: None) -> tuple[UserMesh, UserMesh]:
    """An example pair (A, A1 in A's frame) facing where A faces front (`face_front`); A1 follows A's frame."""
    turned = face_front(transfer, neutral, up_known=up_known, progress=progress)
    if turned.frame == neutral.frame:
        return turned, posed
    return turned, with_frame(posed, turned.frame)
