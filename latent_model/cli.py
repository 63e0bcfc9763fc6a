"""`lrr` command line: build and inspect the corpus, train, build the latent bank, evaluate, predict.

Every heavy import (torch, libigl, anny) happens inside the command that needs it, so `lrr --help`
and argument errors answer at once.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from latent_model.config import corpus_preset, default_corpus_dir
from latent_model.errors import UserFacingError
from latent_model.meshio import EXPORT_FORMATS
from latent_model.types import PRESETS


class UserError(UserFacingError):
    """A bad command line the user can fix; printed without a traceback."""


def _corpus_path(args) -> Path:
    return Path(args.corpus) if getattr(args, "corpus", None) else default_corpus_dir(args.preset)


def _open_corpus(args):
    from latent_model.corpus.store import Corpus

    return Corpus(_corpus_path(args))


def _parse_shard(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise UserError(f"--shard {text!r}: expected I/N, e.g. 0/4") from None
    if not 0 <= i < n:
        raise UserError(f"--shard {text}: need 0 <= I < N")
    return i, n


def cmd_build(args) -> None:
    from tqdm import tqdm

    from latent_model.corpus.build import build

    cfg = corpus_preset(args.preset)
    out = Path(args.out) if args.out else default_corpus_dir(args.preset)
    shard = _parse_shard(args.shard)
    bar = tqdm(total=None, unit="identity", desc=f"corpus {args.preset}", disable=args.quiet)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    r = build(cfg, out, workers=args.workers, shard=shard, force=args.force, progress=progress)
    bar.close()
    if r.identities_built == 0 and r.seconds == 0.0:
        print(f"{out}: already built for preset {args.preset} (use --force to rebuild)")
    else:
        sdf_per_s = r.geometries_built / r.sdf_seconds * args.workers if r.sdf_seconds else float("nan")
        mesh_per_s = r.geometries_built / r.mesh_seconds * args.workers if r.mesh_seconds else float("nan")
        print(f"built {r.identities_built} identities, {r.geometries_built} geometries in {r.seconds:.1f} s "
              f"({r.geometries_built / max(r.seconds, 1e-9):.1f} states/s overall; per worker-second: "
              f"{mesh_per_s / args.workers:.1f} meshes/s, {sdf_per_s / args.workers:.1f} SDF states/s; "
              f"{args.workers} workers)")
    if shard is None and (out / "manifest.json").exists():
        args.corpus = str(out)
        cmd_info(args)
    elif shard is not None:
        print(f"shard {shard[0]}/{shard[1]} written to {out}; join shards with `lrr corpus merge --out DIR SHARD...`")


def cmd_merge(args) -> None:
    from tqdm import tqdm

    from latent_model.corpus.build import merge

    bar = tqdm(unit="identity", desc="merge")

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    out = merge([Path(p) for p in args.shards], Path(args.out), progress=progress)
    bar.close()
    print(f"merged {len(args.shards)} shards into {out}")


def cmd_info(args) -> None:
    import numpy as np

    from latent_model.corpus.build import corpus_variety
    from latent_model.corpus.inspect import corrective_table, offset_copy_explained
    from latent_model.corpus.poses import get_pose

    c = _open_corpus(args)
    m = c.manifest
    sizes = {p.name: p.stat().st_size for p in c.path.glob("*.npy")}
    print(f"corpus {c.path}  (preset {c.config.preset}, format v{m['format_version']}, "
          f"generator v{m.get('generator_version', 3)}, digest {m['config_digest']})")
    print(f"identities {len(c.identities)} characters of {len({s.person_id for s in c.identities})} persons "
          f"(a character: a person in one rest configuration)")
    for split in ("train", "val", "test"):
        ids = [c.identities[i] for i in c.split_indices(split)]
        if ids:
            persons = {s.person_id for s in ids}
            styl = sorted({s.person_id for s in ids if s.stylised})
            print(f"  {split:5s} {len(persons):3d} persons, {len(ids):3d} characters; stylised: {', '.join(styl) or '-'}")
    singles = [p for p in c.poses if not get_pose(p).is_combo]
    print(f"poses {len(c.poses)} ({len(singles)} single, {len(c.poses) - len(singles)} combined); "
          f"states {m['n_states']}; geometries {m['n_geometries']}; vertices/mesh {m['n_vertices']}; "
          f"SDF samples/state {c.config.sdf.k}; disk {sum(sizes.values()) / 1e9:.2f} GB")
    v = corpus_variety(c)
    print("variety (neutral meshes, pelvis-aligned, mean per-vertex distance):")
    print(f"  nearest-identity distance: median {v['nearest_median_mm']:.1f} mm, min {v['nearest_min_mm']:.1f} mm; "
          f"pairwise median {v['pairwise_median_mm']:.1f} mm, max {v['pairwise_max_mm']:.1f} mm")
    print(f"  stature {v['stature_min_m']:.2f}-{v['stature_max_m']:.2f} m (median {v['stature_median_m']:.2f}); "
          f"volume {v['volume_min_l']:.1f}-{v['volume_max_l']:.1f} L (median {v['volume_median_l']:.1f})")
    persons = [s for s in c.identities if s.rest == "bind"]
    sexes = [s.phenotypes.get("gender", 0.5) for s in persons]
    muscle, weight = ([s.phenotypes.get(k, .5) for s in persons] for k in ("muscle", "weight"))
    print(f"  sex: {sum(g >= 0.5 for g in sexes)} male / {sum(g < 0.5 for g in sexes)} female; "
          f"muscle {min(muscle):.2f}-{max(muscle):.2f}, weight {min(weight):.2f}-{max(weight):.2f}")
    from latent_model.corpus.rests import get_rest

    print("rest configurations its characters stand in (degrees from anny's bind pose; all: `lrr corpus rests`):")
    for r in c.rests:
        users = [s for s in c.identities if s.rest == r]
        print(f"  {get_rest(r).line()}   {len(users):3d} characters ({', '.join(sorted({s.split for s in users}))})")
    if args.brief:
        return
    print("pose-space correctives |V_skin+bs - V_skin| (mm; max over identities, mean over moved vertices, std of per-identity max):")
    for row in corrective_table(c):
        print(f"  {row['pose']:40s} max {row['max_mm']:6.2f}  mean {row['mean_mm']:5.2f}  id-std {row['max_std_mm']:5.2f}")
    face = [p for p in singles if get_pose(p).group == "face"]
    body = [p for p in singles if get_pose(p).group == "body"]
    fe = offset_copy_explained(c, face)
    be = offset_copy_explained(c, body)
    print("nearest-identity vertex-offset copy, explained motion (1 - err/err_no_motion), all identities:")
    print(f"  facial poses: mean {np.mean(list(fe.values())):.3f}  ({', '.join(f'{k} {x:.2f}' for k, x in fe.items())})")
    print(f"  body poses:   mean {np.mean(list(be.values())):.3f}")


def cmd_poses(args) -> None:
    from latent_model.corpus.poses import POSES, pose_line

    names = list(POSES)
    if getattr(args, "corpus", None) or args.preset:
        cfg = corpus_preset(args.preset) if args.preset else None
        names = list(cfg.pose_names()) if cfg else names
    for n in names:
        print(pose_line(POSES[n]))
    print(f"{len(names)} poses")


def cmd_rests(args) -> None:
    from latent_model.corpus.rests import REST_CONFIGS

    print("rest configurations (degrees from anny's bind pose, both sides; `test` ones are held out):")
    for r in REST_CONFIGS.values():
        print(f"  {r.line()}")


def cmd_identities(args) -> None:
    """Write the corpus's identity specs and pose names (what the explorer regenerates held-out truth from)."""
    from latent_model.atomic import atomic_write_json

    c = _open_corpus(args)
    m = c.manifest
    atomic_write_json(Path(args.output), {"preset": m.get("preset", args.preset), "poses": list(c.poses),
                                          "identities": m["identities"]})
    print(f"wrote {args.output}: {len(m['identities'])} characters, {len(c.poses)} poses")


def cmd_examples(args) -> None:
    from latent_model.corpus.examples import EXAMPLES, example_pair, get_example
    from latent_model.corpus.rests import get_rest

    print("example deformations outside the pose vocabulary (transfer from an example pair is judged on them):")
    for e in EXAMPLES.values():
        joints = ", ".join(f"{j.bone}:{j.axis}:{j.degrees:+.0f}" for j in e.pose.joints)
        print(f"  {e.name:30s} {e.kind:11s} {e.description}  [{joints}]")
    if not args.output:
        return
    from latent_model.corpus.states import StateGenerator
    from latent_model.meshio import export_mesh, from_identity
    from latent_model.shipped import load_identity_specs

    specs, _ = load_identity_specs()
    by_id = {x.id: x for x in specs}
    names = args.identities.split(",") if args.identities else [x.id for x in specs if x.split == "test"][:4]
    unknown = [n for n in names if n not in by_id]
    if unknown:
        raise UserError(f"unknown identities {unknown}; valid: {', '.join(by_id)}")
    chosen = [get_example(n) for n in (args.examples.split(",") if args.examples else EXAMPLES)]
    get_rest(args.rest)
    gen = StateGenerator()
    out = Path(args.output)
    for e in chosen:
        pair = example_pair(gen, [by_id[n] for n in names], e.name, args.rest)
        meshes = {f"{pair.source}_neutral": pair.source_neutral, f"{pair.source}_deformed": pair.source_deformed}
        for ident, (neutral, truth) in pair.targets.items():
            meshes[f"{ident}_neutral"], meshes[f"{ident}_truth"] = neutral, truth
        for stem, v in meshes.items():
            path = out / e.name / f"{stem}.obj"
            path.parent.mkdir(parents=True, exist_ok=True)
            export_mesh(from_identity(v, gen.faces, stem), v, path)
        print(f"wrote {out / e.name}: the pair of {pair.source} and the truth of {', '.join(pair.targets)} ({args.rest})")


def cmd_export(args) -> None:
    from latent_model.meshio import export_mesh, from_identity

    out = Path(args.output)
    if out.suffix.lower() not in EXPORT_FORMATS:
        raise UserError(f"{out}: unsupported format {out.suffix or '(none)'}; use one of {', '.join(EXPORT_FORMATS)}")
    c = _open_corpus(args)
    try:
        s = c.parse_state(args.state)
    except KeyError as e:
        raise UserError(str(e).strip("'\"")) from None
    v = c.vertices(s)
    export_mesh(from_identity(v, c.faces, c.state_name(s), c.body_faces), v, out)
    print(f"wrote {c.state_name(s)} to {out} ({len(v)} vertices, {len(c.faces)} faces)")


def cmd_sheet(args) -> None:
    from latent_model.corpus.sheet import DEFAULT_SHEET_POSES, contact_sheet

    c = _open_corpus(args)
    ids = None
    if args.identities:
        try:
            ids = [c.identity_index(x) for x in args.identities.split(",")]
        except KeyError as e:
            raise UserError(str(e).strip("'\"")) from None
    poses = tuple(args.poses.split(",")) if args.poses else DEFAULT_SHEET_POSES
    for p in poses:
        if p != "neutral":
            try:
                c.pose_index(p)
            except KeyError as e:
                raise UserError(str(e).strip("'\"")) from None
    if args.rests:
        from latent_model.corpus.sheet import rest_sheet

        specs = [c.identities[i] for i in (ids if ids is not None else range(min(4, len(c.identities))))]
        poses = tuple(args.poses.split(",")) if args.poses else ("neutral",)
        out = rest_sheet(specs, Path(args.output), tuple(args.rests.split(",")), poses)
    else:
        out = contact_sheet(c, Path(args.output), ids, poses)
    print(f"wrote {out}")


def cmd_train(args) -> None:
    from latent_model.train.loop import close_distributed, init_distributed

    init_distributed()
    done = False
    try:
        {"detail": _train_detail, "correctives": _train_correctives}.get(args.phase, _train)(args)
        done = True
    finally:
        close_distributed(wait=done)


def _train_detail(args) -> None:
    """`lrr train detail`: the local detail stage (no corpus needed: the preset's persons are regenerated)."""
    from latent_model.config import data_root, override, preset
    from latent_model.train.local_detail import DetailSection, detail_training, run_local_detail

    p = preset(args.preset)
    try:
        cfg = override(DetailSection(detail_training(args.preset)), args.set or [], sections=("detail",)).detail
    except ValueError as e:
        raise UserError(str(e)) from e
    run_dir = Path(args.run_dir) if args.run_dir else data_root() / "runs" / args.preset
    run_dir.mkdir(parents=True, exist_ok=True)
    out = run_dir / "detail.safetensors"
    print(f"training the local detail stage (head, hands) of preset {args.preset}; -> {out}")
    t = time.perf_counter()
    run_local_detail(p, cfg, out, workers=args.workers, log=print if not args.quiet else (lambda _m: None))
    print(f"done in {time.perf_counter() - t:.1f} s; {out} is read beside {run_dir / 'model.safetensors'}")


def _train_correctives(args) -> None:
    """`lrr train correctives`: the corrective fields (no corpus needed: the preset's persons are regenerated)."""
    from latent_model.config import data_root, preset
    from latent_model.train.corrective_fields import corrective_training, run_correctives

    if args.set:
        raise UserError("lrr train correctives takes no --set (its settings are the preset's)")
    p = preset(args.preset)
    run_dir = Path(args.run_dir) if args.run_dir else data_root() / "runs" / args.preset
    run_dir.mkdir(parents=True, exist_ok=True)
    out = run_dir / "correctives.safetensors"
    print(f"building the corrective fields (skinning -> skinning+blendshape) of preset {args.preset}; -> {out}")
    t = time.perf_counter()
    run_correctives(p, corrective_training(args.preset), out, workers=args.workers,
                    log=print if not args.quiet else (lambda _m: None))
    print(f"done in {time.perf_counter() - t:.1f} s; {out} is read beside {run_dir / 'model.safetensors'}")


def _train(args) -> None:
    from latent_model.config import data_root, override, preset
    from latent_model.corpus.store import Corpus
    from latent_model.runtime import select_device
    from latent_model.train.loop import dist_info
    from latent_model.train.phases import train

    try:
        p = override(preset(args.preset), args.set or [])
    except ValueError as e:
        raise UserError(str(e)) from e
    corpus_dir = Path(args.corpus) if args.corpus else default_corpus_dir(args.preset)
    corpus = Corpus(corpus_dir)
    if corpus.manifest["config_digest"] != p.corpus.digest():
        raise UserError(f"corpus {corpus_dir} was built with another config than preset {args.preset!r}; "
                        f"build it with `lrr corpus build --preset {args.preset}` or pass --corpus")
    run_dir = Path(args.run_dir) if args.run_dir else data_root() / "runs" / args.preset
    phases = {"phase-a": "a", "phase-b": "b", "all": "all", "motion": "motion"}[args.phase]
    device = select_device()
    rank, world = dist_info()
    if rank == 0:
        print(f"training {args.phase} of preset {args.preset} on {device} ({world} process(es)); run dir {run_dir}")
    t = time.perf_counter()
    final = train(p, corpus, run_dir, phases, device=device, fresh=args.fresh, progress=not args.quiet)
    if rank == 0:
        print(f"done in {time.perf_counter() - t:.1f} s; model: {final}; logs and loss curves in {run_dir}")


def cmd_bank(args) -> None:
    from latent_model.bank import build_bank
    from latent_model.corpus.store import Corpus
    from latent_model.checkpoint import load_checkpoint
    from latent_model.runtime import select_device

    model, p, _ = load_checkpoint(Path(args.checkpoint))
    corpus = Corpus(Path(args.corpus) if args.corpus else default_corpus_dir(p.name))
    device = select_device()
    bank = build_bank(model.to(device).eval(), corpus, device, progress=not args.quiet)
    out = Path(args.out)
    bank.save(out)
    print(f"latent bank of {len(bank.keys)} training states, {len(bank.deltas)} (pair kind, pose) deltas -> {out}")
    print(f"noise floor {bank.noise_floor:.3f}; out-of-distribution threshold "
          + (f"{bank.ood_threshold:.2f} for a neutral source, {bank.ood_threshold_posed:.2f} for a posed one (the farthest "
             "validation character's distance to the training states)"
             if bank.ood_threshold > 0 else "none (the corpus has no validation split)"))


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="lrr", description="LatentReRig: corpus, training, evaluation, prediction")
    sub = ap.add_subparsers(dest="command", required=True)
    corpus = sub.add_parser("corpus", help="build and inspect the rig-generated corpus")
    cs = corpus.add_subparsers(dest="corpus_command", required=True)

    def with_corpus(p, preset_default="standard"):
        p.add_argument("--preset", default=preset_default, choices=PRESETS,
                       help=f"preset whose default corpus location is used (default {preset_default})")
        p.add_argument("--corpus", help="corpus directory (overrides --preset's default location)")
        return p

    b = cs.add_parser("build", help="build (or resume) a corpus")
    b.add_argument("--preset", required=True, choices=PRESETS)
    b.add_argument("--out", help="output directory (default: $LRR_DATA/corpus/PRESET, LRR_DATA defaults to ~/.cache/latentrerig)")
    b.add_argument("--workers", type=int, default=max(1, min(2, os.cpu_count() or 1)), help="worker processes (default: 2)")
    b.add_argument("--shard", help="build only shard I/N of the identities (merge shards with `lrr corpus merge`)")
    b.add_argument("--force", action="store_true", help="replace an existing corpus or unfinished build of another config")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.add_argument("--brief", action="store_true", help="print only the short summary afterwards")
    b.set_defaults(func=cmd_build)

    mg = cs.add_parser("merge", help="join shard outputs into one corpus")
    mg.add_argument("--out", required=True)
    mg.add_argument("shards", nargs="+")
    mg.set_defaults(func=cmd_merge)

    i = with_corpus(cs.add_parser("info", help="summary: sizes, split, variety, correctives, offset-copy baseline"))
    i.add_argument("--brief", action="store_true", help="skip the corrective table and the offset-copy baseline")
    i.set_defaults(func=cmd_info)

    p = cs.add_parser("poses", help="the pose vocabulary: name, single/combo, skeletal and blendshape parts")
    p.add_argument("--preset", choices=PRESETS, help="only the poses of this preset (default: whole vocabulary)")
    p.set_defaults(func=cmd_poses)

    ex = cs.add_parser("examples", help="the example deformations outside the vocabulary; -o writes their meshes")
    ex.add_argument("-o", "--output", help="write each example's pair and its targets' truth (OBJ) under this folder")
    ex.add_argument("--identities", help="comma-separated shipped identities, the first makes the pair "
                                         "(default: the first four held-out ones)")
    ex.add_argument("--examples", help="comma-separated example names (default: all)")
    ex.add_argument("--rest", default="bind", help="rest configuration they stand in (default bind)")
    ex.set_defaults(func=cmd_examples)

    ids = with_corpus(cs.add_parser("identities", help="write the identity specs (assets/identities.json) of a corpus"))
    ids.add_argument("-o", "--output", required=True, help="output JSON, e.g. assets/identities.json")
    ids.set_defaults(func=cmd_identities)

    rs = cs.add_parser("rests", help="the rest configurations (arms, elbows, legs, spine angles) and which are held out")
    rs.set_defaults(func=cmd_rests)

    e = with_corpus(cs.add_parser("export", help="write one state as a mesh file"))
    e.add_argument("state", help="ID/POSE/VARIANT or ID/neutral, e.g. id003/elbowBentLf/skinning_plus_blendshape")
    e.add_argument("-o", "--output", required=True, help=f"output mesh ({' '.join(EXPORT_FORMATS)})")
    e.set_defaults(func=cmd_export)

    s = with_corpus(cs.add_parser("sheet", help="render a contact sheet (identities x poses) to PNG"))
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--identities", help="comma-separated ids (default: the first 8)")
    s.add_argument("--poses", help="comma-separated poses ('neutral' allowed)")
    s.add_argument("--rests", help="comma-separated rest configurations (`lrr corpus rests` lists them): the "
                                   "identities across them, generated through the rig")
    s.set_defaults(func=cmd_sheet)

    t = sub.add_parser("train", help="train Phase A (SDF-VAE), Phase B (vertex decoder) or both; resumes")
    t.add_argument("phase", choices=("phase-a", "phase-b", "all", "motion", "detail", "correctives"),
                   help="motion: decoder v2 alone, on the run's finished Phase B (phase_b.safetensors); detail: the "
                        "local detail stage (faces, fingers) -> RUN_DIR/detail.safetensors; correctives: the corrective "
                        "fields -> RUN_DIR/correctives.safetensors; neither needs a corpus")
    t.add_argument("--preset", required=True, choices=PRESETS)
    t.add_argument("--corpus", help="corpus directory (default: the preset's)")
    t.add_argument("--run-dir", help="run directory for checkpoints, logs, loss curves (default: $LRR_DATA/runs/PRESET)")
    t.add_argument("--fresh", action="store_true", help="ignore resume state and start the phase(s) over")
    t.add_argument("--set", action="append", metavar="SECTION.FIELD=VALUE",
                   help="override one preset field for this run (repeatable; stored in the checkpoint), "
                        "e.g. --set train.a_steps=3000 --set loss.mirror=0")
    t.add_argument("--workers", type=int, default=2, help="detail, correctives: processes posing (and sampling) the characters")
    t.add_argument("--quiet", action="store_true", help="no progress bars")
    t.set_defaults(func=cmd_train)

    bk = sub.add_parser("bank", help="encode the training states once: standardisation + deltas per pose and pair kind")
    bk.add_argument("--checkpoint", required=True, help="trained model (safetensors)")
    bk.add_argument("--corpus", help="corpus directory (default: the checkpoint preset's)")
    bk.add_argument("-o", "--out", required=True, help="output .safetensors")
    bk.add_argument("--quiet", action="store_true")
    bk.set_defaults(func=cmd_bank)

    # evaluation and prediction live in their own modules (argument lists included)
    from latent_model.analysis import report
    from latent_model import predict

    ev = sub.add_parser("evaluate", help="the paper's analyses + baselines on held-out identities -> markdown, PNG, metrics.json")
    report.add_arguments(ev)
    ev.set_defaults(func=report.run_cli)

    pr = sub.add_parser("predict", help="deform your own mesh file with a pose (the Transfer API)")
    predict.add_arguments(pr)
    pr.set_defaults(func=predict.run_cli)

    tr = sub.add_parser("transfer", help="deform your mesh B as an example pair A -> A1 deforms A (the Transfer API)")
    predict.add_transfer_arguments(tr)
    tr.set_defaults(func=predict.run_transfer_cli)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from latent_model.runtime import keep_freed_memory

    keep_freed_memory()  # large temporaries reused instead of page-faulted in at every step
    try:
        args.func(args)
    except (UserFacingError, ValueError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"lrr: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lrr: interrupted (a corpus build resumes where it stopped)", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
