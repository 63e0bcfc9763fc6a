"""`lrr predict`: deform a user's mesh file with a pose, through the Transfer API.

    lrr predict --mesh in.obj --pose elbowBentLf [--pose-b kneeBentLf --blend 0.3] \
        --strategy nearest --magnitude 1.0 [--kind neutral_to_pose] [--up auto|y|z] \
        [--units auto|m|cm|mm] [--facing auto|+x|-x|+y|-y|+z|-z] \
        [--checkpoint model.safetensors --bank bank.safetensors] -o out.obj

The mesh is normalised into the model frame (latent_model.meshio; which way it faces, when not told, by the
model: latent_model.facing), prepared and predicted by
`Transfer.prepare` / `Transfer.predict`, and written back in the input's frame, units and
vertex order (atomically: an existing output is replaced only by a complete file).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, get_args

import numpy as np

from latent_model.errors import UserFacingError
from latent_model.facing import face_front, face_front_pair
from latent_model.meshio import EXPORT_FORMATS, FORMATS, MeshError, UserMesh, export_mesh, load_example_pair, load_mesh
from latent_model.types import (MAGNITUDE_RANGE, Facing, PairKind, Strategy, Units, UpAxis, check_blend, check_magnitude,
                                 check_pair_kind, parse_strategy)

if TYPE_CHECKING:
    from latent_model.transfer import PreparedMesh, TransferOutput


class PredictError(UserFacingError, ValueError):
    """A bad request to `lrr predict` (unknown pose, bad slider value, missing model)."""


def check_pose(transfer, pose: str, kind: str) -> None:
    """Raise PredictError listing the valid names when the bank has no delta for `pose`."""
    try:
        check_pair_kind(kind)
    except ValueError as e:
        raise PredictError(str(e)) from None
    valid = transfer.bank.poses(kind)
    if pose not in valid:
        raise PredictError(f"unknown pose {pose!r} for pair kind {kind}. Valid poses ({len(valid)}): {', '.join(valid)}")


def load_transfer(checkpoint: str | Path | None = None, bank: str | Path | None = None):
    """The Transfer API on the shipped model (or the given files)."""
    from latent_model.shipped import AssetsError, ShippedPaths
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    ck = Path(checkpoint) if checkpoint else paths.checkpoint
    bk = Path(bank) if bank else paths.bank
    for p, what in ((ck, "--checkpoint"), (bk, "--bank")):
        if not p.exists():
            raise PredictError(f"{p} does not exist; pass {what} or restore the shipped assets/ (or set LRR_ASSETS)")
    try:
        return Transfer.from_files(ck, bk)
    except AssetsError as e:
        raise PredictError(str(e)) from None


def predict_file(transfer, mesh: UserMesh, pose: str, strategy: Strategy = "mean_pose_delta", magnitude: float = 1.0,
                 kind: PairKind = "neutral_to_pose", pose_b: str | None = None, blend: float = 0.0,
                 seed: int = 0) -> tuple["TransferOutput", "PreparedMesh", float]:
    """(the Transfer output: vertices (W, 3), conditioning label, noise gate...; the prepared mesh,
    which says what was derived from it; seconds) of a loaded mesh."""
    check_pose(transfer, pose, kind)
    if pose_b is not None:
        check_pose(transfer, pose_b, kind)
    try:
        check_magnitude(magnitude)
        check_blend(blend)
        parse_strategy(strategy)
    except ValueError as e:
        raise PredictError(f"{e} (see lrr predict --help)") from None
    if blend > 0 and pose_b is None:
        raise PredictError("--blend needs --pose-b (the pose to blend toward)")
    t0 = time.perf_counter()
    prepared = transfer.prepare_user_mesh(mesh, seed)
    try:
        result = transfer.predict_detail(prepared, pose, strategy, magnitude, kind, pose_b, blend)
    except KeyError as e:  # bank lookups (e.g. identity:<id> not a training identity)
        raise PredictError(str(e).strip("'\"")) from None
    return _with_novelty(transfer, result, prepared, kind), prepared, time.perf_counter() - t0


PREDICTOR_NAMES = {"motion": "motion decoder", "pose_fields": "pose fields", "network": "vertex decoder network",
                   "correctives": "corrective fields"}


def _with_novelty(transfer, result: "TransferOutput", prepared: "PreparedMesh", kind: str) -> "TransferOutput":
    """The result with the mesh's novelty as a source of pair kind `kind` (`Transfer.judged_novelty`)."""
    from dataclasses import replace

    return replace(result, novelty=transfer.judged_novelty(result, prepared, kind))


def transfer_example_file(transfer, neutral: UserMesh, posed: UserMesh, mesh: UserMesh, magnitude: float = 1.0,
                          kind: PairKind = "neutral_to_pose", seed: int = 0) -> tuple["TransferOutput", dict, float]:
    """Deform `mesh` by the deformation of the example pair (neutral -> posed, one topology): (the Transfer
    output, the novelty of each mesh the model read by name, seconds)."""
    try:
        check_pair_kind(kind)
        check_magnitude(magnitude)
    except ValueError as e:
        raise PredictError(f"{e} (see lrr transfer --help)") from None
    t0 = time.perf_counter()
    a, a1 = (transfer.prepare_user_mesh(m, seed) for m in (neutral, posed))
    delta = transfer.example_delta(a, a1)
    target = transfer.prepare_user_mesh(mesh, seed)
    corrective = transfer.example_corrective(a, a1) if transfer.predicts_with(kind) == "correctives" else None
    body = transfer.example_body(a, a1) if kind == "neutral_to_pose" else None
    result = _with_novelty(transfer, transfer.predict_detail(target, None, magnitude=magnitude, kind=kind, delta=delta,
                                                             detail_delta=transfer.example_detail(a, a1),
                                                             corrective_mix=corrective, body_reading=body), target, kind)
    novelty = {mesh.name: result.novelty}
    if transfer.bank.ood_threshold > 0:
        novelty[neutral.name] = transfer.novelty(a)
    return result, novelty, time.perf_counter() - t0


def _frame_model_output_arguments(p, whose: str) -> None:
    """--up, --units, --checkpoint, --bank and -o, shared by `lrr predict` and `lrr transfer`."""
    p.add_argument("--up", default="auto", choices=get_args(UpAxis), help="up axis of the file(s) (default: detected)")
    p.add_argument("--units", default="auto", choices=get_args(Units), help="units of the file(s) (default: detected)")
    p.add_argument("--facing", default="auto", choices=get_args(Facing),
                   help="the file axis the character faces, written --facing=+x (default: the up axis's convention, "
                        "Y-up +Z, Z-up -Y; a mesh the model finds out of distribution that way is tried facing the "
                        "other axes)")
    p.add_argument("--checkpoint", help="trained model (default: the shipped assets/model/model.safetensors)")
    p.add_argument("--bank", help="latent bank (default: the shipped assets/model/bank.safetensors)")
    p.add_argument("-o", "--output", required=True,
                   help=f"output mesh ({' '.join(EXPORT_FORMATS)}), in {whose} frame and units")


def add_arguments(p) -> None:
    p.add_argument("--mesh", required=True, help=f"input mesh ({' '.join(FORMATS)})")
    p.add_argument("--pose", required=True, help="pose name, e.g. elbowBentLf (`lrr corpus poses` lists them)")
    p.add_argument("--pose-b", help="second pose to blend toward")
    p.add_argument("--blend", type=float, default=0.0, help="0 = pose A, 1 = pose B (default 0)")
    p.add_argument("--strategy", default="mean",
                   help="mean (mean pose delta, default: it transfers best on held-out bodies), "
                        "nearest (nearest identity delta) or identity:<id>")
    p.add_argument("--magnitude", type=float, default=1.0, help="scales the delta magnitude r, in [%g, %g] (default 1)" % MAGNITUDE_RANGE)
    p.add_argument("--kind", default="neutral_to_pose", help="pair kind (default neutral_to_pose)")
    _frame_model_output_arguments(p, "the input's")


def _check_output(out: Path) -> None:
    if out.suffix.lower() not in EXPORT_FORMATS:
        raise MeshError(f"{out}: cannot export {out.suffix or '(no extension)'}; use one of {', '.join(EXPORT_FORMATS)}")


def _print_result(result: "TransferOutput", novelty: dict) -> None:
    for name, n in novelty.items():
        if n is not None and (w := n.warning(name)):
            print(w)
    if result.note:
        print(f"note: {result.note}")
    if result.predictor == "correctives":
        pass  # the corrective fields read no latent delta: no noise gate
    elif result.gate == 0.0 and result.detail:
        print("body motion: none; the local detail stage alone moves this pose")
    elif result.gate < 1.0:
        print(f"noise gate {result.gate:.2f}: the conditioning delta is {result.signal:.1f}x its sampling noise "
              f"(the latent noise floor, over sqrt(N) for a mean of N deltas; below 1.5x it carries no usable signal "
              f"and the {'body motion' if result.detail else 'prediction'} keeps the source)")
    if result.detail:
        from latent_model.detail import describe_mix

        print("local detail (faces, fingers): " + ", ".join(
            f"{r.replace('_', ' ')} gate {g:.2f}" + (f" (reads as {describe_mix(result.detail_mix[r])})"
                                                      if result.detail_mix.get(r) else "")
            for r, g in result.detail.items()))


def run_cli(args) -> None:
    out = Path(args.output)
    _check_output(out)
    t0 = time.perf_counter()
    mesh = load_mesh(args.mesh, up=args.up, units=args.units, facing=args.facing)
    t_load = time.perf_counter() - t0
    transfer = load_transfer(args.checkpoint, args.bank)
    if args.facing == "auto":
        mesh = face_front(transfer, mesh, args.kind, up_known=args.up != "auto", progress=print)
    result, prepared, t_pred = predict_file(transfer, mesh, args.pose, args.strategy, args.magnitude,
                                            args.kind, args.pose_b, args.blend)
    verts, label = result.vertices, result.label
    export_mesh(mesh, verts, out)
    disp = np.linalg.norm(verts - mesh.vertices, axis=1) * 1000
    what = args.pose + (f" -> {args.pose_b} ({args.blend:g})" if args.pose_b and args.blend > 0 else "")
    print(f"{mesh.summary()}")
    print(f"{what}, strategy {args.strategy} (conditioning: {label}), magnitude {args.magnitude:g}: "
          f"displacement mean {disp.mean():.1f} mm, max {disp.max():.1f} mm")
    _print_result(result, {mesh.name: result.novelty})
    used = "its latent encoded" if "mu" in prepared.derived() else "no latent needed"
    print(f"predicted by the {PREDICTOR_NAMES.get(result.predictor, result.predictor)} ({used}); "
          f"wrote {out} (import {t_load:.2f} s, predict {t_pred:.2f} s)")


def add_transfer_arguments(p) -> None:
    p.add_argument("--example-neutral", required=True, help=f"a character's mesh A ({' '.join(FORMATS)})")
    p.add_argument("--example-posed", required=True, help="the same mesh deformed, A1 (A's vertices and triangles)")
    p.add_argument("--mesh", required=True, help="the character B to deform the same way (any topology)")
    p.add_argument("--magnitude", type=float, default=1.0, help="scales the example's delta, in [%g, %g] (default 1)" % MAGNITUDE_RANGE)
    p.add_argument("--kind", default="neutral_to_pose", help="pair kind of the example (default neutral_to_pose)")
    _frame_model_output_arguments(p, "B's")


def run_transfer_cli(args) -> None:
    """`lrr transfer`: deform B as the example pair A -> A1 deforms A."""
    out = Path(args.output)
    _check_output(out)
    neutral, posed = load_example_pair(args.example_neutral, args.example_posed, args.up, args.units, args.facing)
    mesh = load_mesh(args.mesh, up=args.up, units=args.units, facing=args.facing)
    transfer = load_transfer(args.checkpoint, args.bank)
    if args.facing == "auto":
        known = args.up != "auto"
        neutral, posed = face_front_pair(transfer, neutral, posed, up_known=known, progress=print)
        mesh = face_front(transfer, mesh, up_known=known, progress=print)
    result, novelty, seconds = transfer_example_file(transfer, neutral, posed, mesh, args.magnitude, args.kind)
    export_mesh(mesh, result.vertices, out)
    example = np.linalg.norm(posed.vertices - neutral.vertices, axis=1) * 1000
    disp = np.linalg.norm(result.vertices - mesh.vertices, axis=1) * 1000
    print(f"example {neutral.name} -> {posed.name}: displacement mean {example.mean():.1f} mm, max {example.max():.1f} mm")
    print(f"{mesh.summary()}")
    print(f"magnitude {args.magnitude:g}: displacement mean {disp.mean():.1f} mm, max {disp.max():.1f} mm")
    _print_result(result, novelty)
    print(f"predicted by the {PREDICTOR_NAMES.get(result.predictor, result.predictor)}; wrote {out} ({seconds:.2f} s)")
