"""`lrr evaluate`: every quantitative analysis of the paper on held-out identities, the
no-learning baseline beside the model, mesh transfer with honest baselines -> report.md,
metrics.json (stable flat keys) and PNG figures in one directory."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from latent_model.analysis.parallel import Workers, resolve_workers

# The paper's numbers (Tables 2-3, sections 6.2 and 7), shown beside ours.
PAPER = {
    "latent.pose_consistency.elbowBentLf.cos_mean": 0.958,
    "latent.pose_consistency.clavicleDownwardLf.cos_mean": 0.932,
    "latent.pose_consistency.browDwLf.cos_mean": 0.777,
    "latent.pose_consistency.puffLf.cos_mean": 0.743,
    "latent.identity_distance.mean": 27.01, "latent.identity_distance.median": 25.29,
    "latent.identity_distance.std": 9.66, "latent.identity_distance.min": 11.70, "latent.identity_distance.max": 61.08,
    "latent.noise_distance.mean": 8.30, "latent.noise_distance.median": 8.03, "latent.noise_distance.std": 2.56,
    "latent.noise_distance.min": 2.36, "latent.noise_distance.max": 18.33,
    "latent.identity_noise_ratio": 3.26, "latent.ks.D": 0.9368, "latent.ks.p": 3.15e-91,
    "latent.cond_noise.mean": 2.03, "latent.cond_noise.median": 2.06,
    "latent.entanglement.elbowBentLf.posed_identity_distance": 29.22, "latent.entanglement.elbowBentLf.delta_cosine": 0.952,
    "latent.entanglement.fingerKnuckleD03Lf.posed_identity_distance": 31.67,
    "latent.entanglement.fingerKnuckleD03Lf.delta_cosine": 0.921,
    "latent.entanglement.fingerKnuckleA01Lf.posed_identity_distance": 30.10,
    "latent.entanglement.fingerKnuckleA01Lf.delta_cosine": 0.791,
    "latent.entanglement.browDwLf.posed_identity_distance": 29.01, "latent.entanglement.browDwLf.delta_cosine": 0.800,
}
NAMED_POSES = ("elbowBentLf", "elbowSuperBentLf", "kneeBentLf", "clavicleDownwardLf", "fingerKnuckleA01Lf",
               "fingerKnuckleD02Lf", "fingerKnuckleD03Lf", "browDwLf", "browDwRt", "puffLf", "cornerUpLf",
               "cornerPuckerLf", "cornerStretchLf", "jawOpen")
BASELINE_DIMS = (16, 512)
DETAIL_PER_REST = 4  # held-out characters per rest configuration in the local detail section (evaluation time)


def add_arguments(p) -> None:
    p.add_argument("--checkpoint", help="trained model (default: the shipped assets/model/model.safetensors)")
    p.add_argument("--bank", help="its latent bank (default: beside the checkpoint, bank.safetensors)")
    p.add_argument("--corpus", help="corpus directory (default: the checkpoint preset's)")
    p.add_argument("--out", required=True, help="report directory (report.md, metrics.json, *.png)")
    p.add_argument("--transfer-ids", type=int, default=0, help="held-out identities in the mesh analysis (0 = all)")
    p.add_argument("--fresh-caches", "--fresh-baselines", dest="fresh_caches", action="store_true",
                   help="recompute what depends on the corpus alone and is kept in $LRR_DATA/cache: the no-learning "
                        "baselines (cache/baselines), the evaluated meshes' surface features (cache/surface) and the "
                        "SDF re-samplings of the noise-floor analyses (cache/samples)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes sharing each analysis' characters (default: up to 2, one per core)")
    p.add_argument("--detail", help="local detail file (default: detail.safetensors beside the checkpoint, if any)")
    p.add_argument("--correctives", help="corrective fields file (default: correctives.safetensors beside the "
                                         "checkpoint, if any)")
    p.add_argument("--detail-only", action="store_true",
                   help="only the local detail section (faces, fingers, correctives; no corpus needed) -> OUT/detail.md, "
                        "detail.json")
    p.add_argument("--split", choices=("test", "val"), default="test",
                   help="--detail-only: the held-out characters to measure (val to choose settings, test once)")
    p.add_argument("--quiet", action="store_true")


def run_cli(args) -> None:
    from latent_model.config import data_root
    from latent_model.shipped import ShippedPaths

    ckpt = Path(args.checkpoint) if args.checkpoint else ShippedPaths.at().checkpoint
    bank = Path(args.bank) if args.bank else ckpt.with_name("bank.safetensors")
    t = time.perf_counter()
    if args.detail_only:
        out = evaluate_detail_only(ckpt, bank, Path(args.detail) if args.detail else None, args.split, Path(args.out),
                                   args.transfer_ids, progress=not args.quiet,
                                   correctives=Path(args.correctives) if args.correctives else None,
                                   workers=args.workers)
        print(f"local detail report written to {out} in {time.perf_counter() - t:.0f} s")
        return
    out = evaluate(ckpt, bank, Path(args.corpus) if args.corpus else None, Path(args.out),
                   transfer_ids=args.transfer_ids, progress=not args.quiet,
                   baseline_cache=None if args.fresh_caches else data_root() / "cache" / "baselines",
                   surface_cache=None if args.fresh_caches else data_root() / "cache" / "surface",
                   sample_cache=None if args.fresh_caches else data_root() / "cache" / "samples",
                   workers=args.workers, detail=Path(args.detail) if args.detail else None,
                   correctives=Path(args.correctives) if args.correctives else None)
    print(f"report written to {out} in {time.perf_counter() - t:.0f} s")


def detail_characters(preset, split: str, n: int = 0) -> list:
    """The preset's `split` characters in every rest configuration (bind first), at most `n` per rest (0: all)."""
    from latent_model.corpus.build import plan

    specs, _, _ = plan(preset.corpus)
    held = [s for s in specs if s.split == split]
    rests = sorted({s.rest for s in held}, key=lambda r: (r != "bind", r))
    return [s for r in rests for s in [x for x in held if x.rest == r][:n or None]]


def _detail_transfer(checkpoint: Path, bank: Path, detail: Path | None, correctives: Path | None = None):
    """(Transfer with the local detail stage and the corrective fields (each: the file given, else beside the
    checkpoint, else none; one of them at least), the checkpoint's preset)."""
    from latent_model.bank import LatentBank
    from latent_model.checkpoint import load_checkpoint
    from latent_model.corrective_fields import CorrectiveFields, correctives_beside
    from latent_model.detail import LocalDetailModel, detail_beside
    from latent_model.transfer import Transfer

    path = detail or detail_beside(checkpoint)
    fields = correctives or correctives_beside(checkpoint)
    if path is None and fields is None:
        raise ValueError(f"no local detail or corrective fields file: give --detail / --correctives or put "
                         f"detail.safetensors / correctives.safetensors beside {checkpoint} (`lrr train detail`, "
                         "`lrr train correctives`)")
    model, preset, _ = load_checkpoint(checkpoint)
    return Transfer(model.eval(), LatentBank.load(bank), preset.corpus.sdf.k, None,
                    None if path is None else LocalDetailModel.load(path),
                    None if fields is None else CorrectiveFields.load(fields)), preset


def evaluate_detail_only(checkpoint: Path, bank: Path, detail: Path | None, split: str, out: Path, per_rest: int = 0,
                         progress: bool = True, correctives: Path | None = None, workers: int | None = None) -> Path:
    """`lrr evaluate --detail-only`: the local detail section (faces, fingers, correctives) on the `split`
    characters -> out/detail.md, detail.json. `workers`: processes sharing the characters (None: one per core,
    at most 2)."""
    from latent_model.analysis import corrective_eval
    from latent_model.analysis.detail_eval import markdown, submit_detail
    from latent_model.atomic import atomic_write_json, atomic_write_text

    say = print if progress else (lambda _m: None)
    transfer, preset = _detail_transfer(checkpoint, bank, detail, correctives)
    specs = detail_characters(preset, split, per_rest)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    # both analyses' characters on one set of processes, queued together (`parallel.Workers`)
    with Workers(transfer, None, resolve_workers(workers, len(specs))) as pool:
        detail_batch = submit_detail(transfer, specs, preset.corpus.pose_names(), say=say, workers=pool)
        corrective_batch = corrective_eval.submit_correctives(transfer, specs, say=say, workers=pool)
        m, fig = detail_batch.get()
        m["timing.detail_s"] = time.perf_counter() - t
        m.update(corrective_batch.get())
        m["timing.correctives_s"] = time.perf_counter() - t  # the two overlap: each from the start
    m["meta.detail_characters"] = [s.id for s in specs]
    atomic_write_json(out / "detail.json", m)
    text = f"# Local detail ({split} characters: {', '.join(s.id for s in specs)})\n\n"
    if transfer.detail is not None:
        text += markdown(m) + "\n"
    if fig:
        text += f"\n![{fig['title']}]({_detail_figure(fig, out).name})\n"
    if transfer.correctives is not None:
        text += "\n## Corrective pairs (skinning → skinning+blendshape): explained (worst character)\n\n"
        text += corrective_eval.markdown(m) + "\n"
    atomic_write_text(out / "detail.md", text)
    return out


def _detail_figure(fig: dict, out: Path) -> Path:
    from latent_model.analysis import figures
    from latent_model.analysis.detail_eval import FIGURE_POSE

    return figures.detail_closeup(fig["example"], fig["faces"], fig["region"], fig["title"],
                                  out / f"detail_{FIGURE_POSE}_closeup.png")


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return "–"
    if isinstance(v, int):
        return str(v)
    if abs(v) != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
        return f"{v:.2e}"
    return f"{v:.3f}" if abs(v) < 10 else f"{v:.2f}"


def _table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(x if isinstance(x, str) else _fmt(x) for x in r) + " |" for r in rows]
    return "\n".join(lines)


def check_corpus_matches(meta: dict, checkpoint: Path, corpus) -> None:
    """Raise CorpusError when the checkpoint was trained on a corpus of another config or
    generator version (its ground truth would not be the geometry the model learnt). When the
    checkpoint was trained on an older generator's corpus, the message says so: rebuilding cannot help, only that corpus or a retrained model."""
    from latent_model.corpus.config import GENERATOR_VERSION
    from latent_model.corpus.store import CorpusError

    extra = json.loads(meta.get("extra", "{}"))
    trained_on = extra.get("corpus_digest")
    generator = extra.get("corpus_generator", 3)  # checkpoints before generator 4 did not record it
    have = corpus.manifest["config_digest"]
    if not trained_on or trained_on == have:
        return
    head = (f"checkpoint {checkpoint} was trained on a corpus with digest {trained_on}, but corpus {corpus.path} "
            f"has digest {have}")
    if generator != GENERATOR_VERSION:
        raise CorpusError(f"{head}: the model predates this program's corpus generator (it was trained on generator "
                          f"v{generator}'s corpus, this program builds v{GENERATOR_VERSION}), so `lrr corpus build` "
                          f"no longer makes its corpus. Evaluate it with --corpus pointing at "
                          f"the corpus it was trained on (built by the program version that trained it), or "
                          f"retrain it with `lrr train all --preset {corpus.config.preset}` on today's corpus")
    raise CorpusError(f"{head} (another config or generator version): rebuild the corpus with `lrr corpus build "
                      f"--preset {corpus.config.preset} --force` or evaluate a checkpoint trained on this corpus")


def baseline_analyses(corpus, samples, say, cache: Path | None) -> tuple[dict, dict, bool]:
    """({name: metrics}, {name: figure data}, whether they came from the cache) of the no-learning baselines (grid
    SDF -> PCA, BASELINE_DIMS). They depend on the corpus alone, not on the model under evaluation: kept in `cache`
    (a directory; None: always computed), keyed by the corpus digest and the code of the analyses and of the SDF
    re-sampling, so evaluating a second model skips them."""
    import hashlib
    import pickle

    from latent_model.analysis import latent_space, metrics, sources
    from latent_model.atomic import atomic_write_bytes
    from latent_model.corpus import sdf

    code = b"".join(Path(m.__file__).read_bytes() for m in (latent_space, metrics, sources, sdf))
    key = hashlib.sha256(corpus.manifest["config_digest"].encode() + repr(BASELINE_DIMS).encode() + code).hexdigest()
    path = None if cache is None else Path(cache) / f"baselines_{key[:20]}.pkl"
    if path is not None and path.exists():
        try:
            lat, fig = pickle.loads(path.read_bytes())
            say(f"no-learning baselines from {path} (the same corpus and analysis code)")
            return lat, fig, True
        except Exception as e:  # a cache written by another version: recompute it
            say(f"baseline cache {path} unreadable ({e}); recomputing")
    lat, fig = {}, {}
    grid = sources.SdfGrid(corpus)
    for dims in BASELINE_DIMS:
        say(f"no-learning baseline: grid SDF -> PCA{dims}")
        src = sources.pca_baseline_source(corpus, samples, dims, grid=grid)
        lat[src.name], fig[src.name] = latent_space.latent_analyses(src, corpus, progress=say)
    if path is not None:
        atomic_write_bytes(path, pickle.dumps((lat, fig)))
    return lat, fig, False


def evaluate(checkpoint: Path, bank_path: Path, corpus_dir: Path | None, out: Path, transfer_ids: int = 0,
             progress: bool = True, baseline_cache: Path | None = None, workers: int | None = None,
             detail: Path | None = None, correctives: Path | None = None, surface_cache: Path | None = None,
             sample_cache: Path | None = None) -> Path:
    """`lrr evaluate`: every analysis into out/ (report.md, metrics.json, figures). `baseline_cache`: a directory
    keeping the model-independent baselines between evaluations (`baseline_analyses`; None: computed each time);
    `surface_cache` the same for the surface features of the evaluated corpus meshes (`surface_cache.py`),
    `sample_cache` for the SDF re-samplings of the noise-floor analyses (`sample_cache.KeptSampleCache`).
    `workers`: processes sharing each analysis' characters (None: one per core, at most 2). `detail`: the
    local detail file (None: the checkpoint's `detail.safetensors` if there is one), in every prediction;
    `correctives` the same for the corrective fields."""
    from latent_model.analysis import figures

    resolve_workers(workers, 1)  # a bad count fails before any work
    from latent_model.analysis.latent_space import SampleCache, analysis_identities, latent_analyses, single_poses
    from latent_model.analysis.sample_cache import KeptSampleCache
    from latent_model.analysis.sources import model_source
    from latent_model.analysis.corrective_eval import submit_correctives
    from latent_model.analysis.decoder_eval import submit_decoder
    from latent_model.analysis.detail_eval import submit_detail
    from latent_model.analysis.transfer_eval import submit_transfer
    from latent_model.bank import LatentBank
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.poses import get_pose
    from latent_model.atomic import atomic_write_json, atomic_write_text
    from latent_model.corpus.store import Corpus
    from latent_model.checkpoint import load_checkpoint
    from latent_model.transfer import Transfer
    from latent_model.types import PAIR_KINDS

    def say(msg: str) -> None:
        if progress:
            print(f"[evaluate] {msg}", flush=True)

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    model, preset, meta = load_checkpoint(checkpoint)
    model.eval()
    bank = LatentBank.load(bank_path)
    corpus = Corpus(corpus_dir or default_corpus_dir(preset.name))
    check_corpus_matches(meta, checkpoint, corpus)
    out.mkdir(parents=True, exist_ok=True)
    samples = SampleCache(corpus) if sample_cache is None else KeptSampleCache(corpus, sample_cache)
    test = corpus.split_indices("test")
    singles = single_poses(tuple(corpus.poses))

    from latent_model.corrective_fields import CorrectiveFields, correctives_beside
    from latent_model.detail import LocalDetailModel, detail_beside

    detail = detail or detail_beside(checkpoint)
    correctives = correctives or correctives_beside(checkpoint)
    transfer = Transfer(model, bank, preset.corpus.sdf.k, None, None if detail is None else LocalDetailModel.load(detail),
                        None if correctives is None else CorrectiveFields.load(correctives))
    # every pair kind and pose on the test persons in bind; the other rests in the decoder's analyses
    bind = [i for i in test if corpus.identities[i].rest == "bind"]
    ids = bind[:transfer_ids] if transfer_ids else bind
    persons = {corpus.identities[i].person_id for i in ids}
    held = [i for i in test if corpus.identities[i].person_id in persons]
    # one set of processes for every analysis, queued one behind the other; this process meanwhile runs the latent
    # analyses, prepares the next analyses and draws the figures (stages overlap: each timing is from its start)
    with Workers(transfer, corpus, resolve_workers(workers, len(ids))) as pool:
        say("mesh transfer on held-out identities (queued; the latent analyses meanwhile)")
        t_transfer = time.perf_counter()
        transfer_batch = submit_transfer(transfer, corpus, ids, progress=progress, workers=pool,
                                         surface_cache=surface_cache)
        say("latent analyses of the model")
        t = time.perf_counter()
        sources = {"model": model_source(model, bank, samples)}
        lat = {}
        figdata = {}
        lat["model"], figdata["model"] = latent_analyses(sources["model"], corpus, progress=say)
        timings["latent_model_s"] = time.perf_counter() - t
        t = time.perf_counter()
        base_lat, base_fig, cached = baseline_analyses(corpus, samples, say, baseline_cache)
        lat.update(base_lat)
        figdata.update(base_fig)
        timings["latent_baselines_s"] = time.perf_counter() - t
        tm, examples = transfer_batch.get()
        names = {"motion": "motion decoder (decoder v2)", "network": "vertex decoder network",
                 "pose_fields": "pose fields", "correctives": "corrective fields"}
        tm.update({f"transfer.{k}.predictor": names[transfer.predicts_with(k)] for k in PAIR_KINDS})
        timings["transfer_s"] = time.perf_counter() - t_transfer

        t_rest = time.perf_counter()
        local = detail_characters(preset, "test", DETAIL_PER_REST)
        detail_batch = corrective_batch = None
        if transfer.detail is not None:
            say("local detail (faces, fingers) on the held-out characters, every rest (queued)")
            detail_batch = submit_detail(transfer, local, preset.corpus.pose_names(), say=say, workers=pool)
        if transfer.correctives is not None:
            say("corrective fields on the held-out characters, every rest (queued)")
            corrective_batch = submit_correctives(transfer, local, say=say, workers=pool)
        decoder_batch = submit_decoder(transfer, corpus, held, say, pool, surface_cache)

        say("figures")
        t = time.perf_counter()
        figs = {
            "identity": figures.identity_matrices(figdata, out / "identity_distances.png"),
            "cosine": figures.cosine_heatmaps(figdata["model"], out / "pose_cosines.png", "model"),
            "noise": figures.noise_floor(figdata, out / "noise_floor.png"),
            "entanglement": figures.entanglement(figdata["model"], out / "entanglement.png", "model"),
            "bars": figures.pose_consistency_bars(lat, singles, out / "pose_consistency.png"),
        }
        ex_figs = []
        faces = corpus.faces
        for (kind, pose), ex in sorted(examples.items()):
            name = f"transfer_{kind}_{pose}".replace("+", "_").replace("@", "_from_")
            view = "side" if pose.startswith("knee") else "front"
            crop = None
            if get_pose(pose.split("@")[0]).group == "face":  # zoom on the head
                top = ex["truth"][:, 2].max()
                crop = np.array([[-0.2, -1.0, top - 0.3], [0.2, 1.0, top + 0.01]])
            ex_figs.append((kind, pose, figures.transfer_example(ex, faces, f"{corpus.identities[ids[0]].id} {kind} {pose}",
                                                                 out / f"{name}.png", view, crop)))
        timings["figures_s"] = time.perf_counter() - t

        if detail_batch is not None:
            dm, detail_fig = detail_batch.get()
            tm.update(dm)
            tm["meta.detail_characters"] = [s.id for s in local]
            timings["detail_s"] = time.perf_counter() - t_rest
            if detail_fig:
                figs["detail"] = _detail_figure(detail_fig, out)
        if corrective_batch is not None:
            tm.update(corrective_batch.get())
            timings["correctives_s"] = time.perf_counter() - t_rest
        tm.update(decoder_batch.get())
        timings["decoder_s"] = time.perf_counter() - t_rest

    metrics: dict = dict(lat["model"])
    metrics.update(tm)
    for name in lat:
        if name != "model":
            metrics.update({f"baseline.{name}.{k}": v for k, v in lat[name].items()})
    timings["total_s"] = time.perf_counter() - t0
    metrics.update({f"timing.{k}": v for k, v in timings.items()})
    metrics["meta.checkpoint"] = str(checkpoint)
    metrics["meta.baselines_from_cache"] = cached
    metrics["meta.test_identities"] = [corpus.identities[i].id for i in ids]
    metrics["meta.analysis_identities"] = [corpus.identities[i].id for i in analysis_identities(corpus)]
    atomic_write_json(out / "metrics.json", metrics)
    atomic_write_text(out / "report.md", _markdown(metrics, lat, singles, figs, ex_figs, corpus, ids))
    return out


def _decoder_section(m: dict, singles: list[str]) -> list[str]:
    """Section 6b: the decoder's targets (rests, blends, magnitudes, example pairs, oracle and nearest vs mean)."""
    from latent_model.analysis import decoder_eval

    out = ["## 6b. The decoder: rests, blends, magnitudes, example pairs", "",
           "Test characters: every held-out person in bind and in each held-out rest configuration; blends, "
           "magnitudes and example pairs on the persons in bind. Edge strain: how much the prediction stretches or "
           "crumples the edges that truly move (sum |Δ length| / sum length).", "", decoder_eval.markdown(m)]
    rows = []
    for pose in decoder_eval.BROAD:
        base = f"transfer.neutral_to_pose.{pose}"
        if f"{base}.mean.explained" in m:
            mean, near, orc = (m[f"{base}.{s}.explained"] for s in ("mean", "nearest", "oracle"))
            rows.append([pose, mean, near, orc, "yes" if orc >= mean - 0.02 else "NO",
                         "nearest" if near > mean else "mean"])
    if rows:
        out += ["### Oracle and nearest identity against the mean delta (bind, explained)", "",
                _table(["pose", "mean", "nearest", "oracle", "oracle ≥ mean − 0.02", "better"], rows), ""]
    wins = [p for p in singles if m.get(f"transfer.neutral_to_pose.{p}.nearest.explained", -1)
            > m.get(f"transfer.neutral_to_pose.{p}.mean.explained", 0)]
    out += [f"Nearest identity beats the mean on {len(wins)} of {len(singles)} single poses"
            + (f": {', '.join(wins)}." if wins else "."), ""]
    return out


def _markdown(m: dict, lat: dict, singles: list[str], figs: dict, ex_figs: list, corpus, ids) -> str:
    from latent_model.types import PAIR_KINDS
    from latent_model.corpus.poses import get_pose

    names = list(lat)
    test_names = ", ".join(corpus.identities[i].id for i in corpus.split_indices("test"))
    out = ["# LatentReRig evaluation", "",
           f"Held-out identities: {test_names}. Standardisation: training-state statistics of each encoder. "
           f"Baselines `pca16`/`pca512`: the same SDF samples on a fixed 5 cm grid -> PCA (no learning). "
           f"Evaluation time: {m['timing.total_s']:.0f} s"
           + (" (the baselines from the cache of an earlier evaluation on this corpus)." if m.get("meta.baselines_from_cache")
              else "."), ""]

    out += ["## 1. Pose consistency (cross-identity cosine of Δμ, held-out identities)", ""]
    rests = list(dict.fromkeys(corpus.identities[i].rest for i in corpus.split_indices("test")))
    rest_key = lambda pose, rest: f"latent.pose_consistency.{pose}.rest.{rest}.cos_mean"  # noqa: E731
    rests = [r for r in rests if rest_key(singles[0], r) in m] if singles else []
    if len(rests) > 1:
        out += [f"The held-out characters stand in {len(rests)} rest configurations ({', '.join(rests)}). The paper's "
                "characters share one rest, so its cosine compares with the model's within one rest (the columns "
                "after the baselines); across rests the same joint turn moves a limb elsewhere in space, and an SDF "
                "code sees space.", ""]
    rows = []
    for pose in list(NAMED_POSES) + [p for p in singles if p not in NAMED_POSES]:
        if f"latent.pose_consistency.{pose}.cos_mean" not in m:
            continue
        r = [pose]
        for n in names:
            src = lat[n]
            r += [f"{src[f'latent.pose_consistency.{pose}.cos_mean']:.3f} ± {src[f'latent.pose_consistency.{pose}.cos_std']:.3f}"]
        if len(rests) > 1:
            r += [" / ".join(f"{m[rest_key(pose, x)]:.3f}" for x in rests)]
        r += [m[f"latent.pose_consistency.{pose}.norm_mean"], PAPER.get(f"latent.pose_consistency.{pose}.cos_mean")]
        rows.append(r)
    header = ["pose"] + [f"{n} cos{' (all rests)' if len(rests) > 1 else ''}" for n in names]
    header += [f"model cos within a rest: {' / '.join(rests)}"] if len(rests) > 1 else []
    out += [_table(header + ["model ‖Δμ‖", "paper cos (one rest)"], rows), "",
            f"![pose consistency]({figs['bars'].name})", "", f"![cosine heatmaps]({figs['cosine'].name})", ""]

    out += ["## 2-3. Identity separation and the noise floor", "",
            f"Identity: {m['latent.identity_distance.n']} standardised distances between the neutral means of "
            f"{len(m['meta.analysis_identities'])} identities (every held-out one, then training ones: "
            f"{', '.join(m['meta.analysis_identities'])}). Noise: {m['latent.noise_distance.n']} distances between "
            "independent SDF re-samplings of the same neutral geometry (5 re-samplings per identity, pairs in order).", ""]
    rows = []
    for stat in ("n", "mean", "median", "std", "min", "max"):
        r = [stat]
        for n in names:
            r += [lat[n][f"latent.identity_distance.{stat}"], lat[n][f"latent.noise_distance.{stat}"]]
        r += [PAPER.get(f"latent.identity_distance.{stat}", 190 if stat == "n" else None),
              PAPER.get(f"latent.noise_distance.{stat}", 190 if stat == "n" else None)]
        rows.append(r)
    out += [_table(["statistic"] + [f"{n} {k}" for n in names for k in ("identity", "noise")] + ["paper identity", "paper noise"], rows), ""]
    rows = [[n, lat[n]["latent.identity_noise_ratio"], lat[n]["latent.ks.D"], lat[n]["latent.ks.p"],
             lat[n]["latent.cond_noise.mean"], lat[n]["latent.cond_noise.median"],
             lat[n].get("latent.cond_noise.group.body"), lat[n].get("latent.cond_noise.group.finger"),
             lat[n].get("latent.cond_noise.group.face")] for n in names]
    rows.append(["paper", 3.26, 0.9368, 3.15e-91, 2.03, 2.06, None, None, None])
    out += [_table(["encoder", "identity/noise", "KS D", "KS p (nominal)", "R mean", "R median", "R body", "R finger", "R face"], rows), "",
            "KS D measures how separated the two distance distributions are, but has no direction (D = 1 also when "
            "noise exceeds the identity distances): read it beside the ratio of means. The 190 identity distances "
            "reuse 20 codes, so they are not independent and the nominal p is not a calibrated significance.", "",
            f"![identity distances]({figs['identity'].name})", "", f"![noise floor]({figs['noise'].name})", ""]

    out += ["## 4. R_cond/noise per single pose", "",
            "R = mean standardised ‖Δμ‖ over held-out identities / mean distance between two independent SDF "
            "samplings of the posed state (4 identities).", ""]
    rows = [[p, get_pose(p).group] + [lat[n][f"latent.cond_noise.per_pose.{p}"] for n in names] for p in singles]
    out += [_table(["pose", "group"] + [f"{n} R" for n in names], rows), ""]

    out += ["## 5. Identity–pose entanglement", ""]
    rows = []
    for pose in ("elbowBentLf", "fingerKnuckleD03Lf", "fingerKnuckleA01Lf", "browDwLf"):
        k = f"latent.entanglement.{pose}"
        if f"{k}.delta_cosine" in m:
            rows.append([pose, m[f"{k}.posed_identity_distance"], m[f"{k}.delta_cosine"],
                         PAPER.get(f"{k}.posed_identity_distance"), PAPER.get(f"{k}.delta_cosine")])
    out += [_table(["pose", "ID dist.", "delta cosine", "paper ID dist.", "paper cosine"], rows), "",
            f"![entanglement]({figs['entanglement'].name})", ""]

    out += ["## 6. Mesh prediction on held-out identities", "",
            f"{len(ids)} held-out identities. err = mean per-vertex error (mm); moving = error over vertices that "
            "truly move ≥ 1 mm; leak = mean predicted displacement of vertices that truly move < 1 mm; explained = "
            "1 − err/err(no motion); normal = mean cosine of vertex normals. `offset_*` copy vertex offsets of "
            "training identities — possible only because the corpus shares one topology (a user's mesh has no such "
            "correspondence; the model needs none). The paper reports no mesh-error numbers.", "",
            "mean / nearest / oracle are what the Transfer API returns: the decoder's displacement scaled by the noise "
            "gate (0 when the conditioning delta is under 1.5x its sampling noise, 1 above 3x; the noise is the latent "
            "noise floor for one character's delta, the floor over sqrt(N) for the mean of N). `*_raw` is the "
            "predictor's own output, ungated (the same decoder call; a face or finger pose that the local detail stage "
            "moves alone is not read by the body decoder, so its raw output is the detail stage's, ungated).", ""]
    strategies = ("mean", "nearest", "oracle", "mean_raw", "nearest_raw", "no_motion", "offset_nearest", "offset_mean")
    for kind in PAIR_KINDS:
        rows = []
        for g in ("body", "finger", "face", "mixed", "combo"):
            base = f"transfer_group.{kind}.{g}"
            if f"{base}.mean.err_mm" not in m:
                continue
            rows.append([g] + [f"{m[f'{base}.{s}.err_mm']:.2f} / {m[f'{base}.{s}.explained']:.2f} / {m[f'{base}.{s}.leak_mm']:.2f}"
                               for s in strategies])
        if rows:
            by = m.get(f"transfer.{kind}.predictor")
            out += [f"### {kind} ({f'predicted by the {by}; ' if by else ''}per pose group: err mm / explained / leak mm)", "",
                    _table(["group"] + list(strategies), rows), ""]
    rows = []
    for pose in singles + [p for p in corpus.poses if p not in singles]:
        base = f"transfer.neutral_to_pose.{pose}"
        if f"{base}.mean.err_mm" in m:
            rows.append([pose] + [f"{m[f'{base}.{s}.err_mm']:.2f} / {m[f'{base}.{s}.explained']:.2f}" for s in strategies]
                        + [m[f"{base}.mean.leak_mm"], m[f"{base}.nearest.leak_mm"]])
    out += ["### neutral_to_pose per pose (err mm / explained)", "",
            _table(["pose"] + list(strategies) + ["leak mean", "leak nearest"], rows), ""]
    rows = []
    for pose in corpus.poses:
        base = f"transfer.skinning_to_skinning_plus_blendshape.{pose}"
        if f"{base}.mean.err_mm" in m:
            best = min(m[f"{base}.mean.err_mm"], m[f"{base}.nearest.err_mm"])
            best_raw = min(m[f"{base}.mean_raw.err_mm"], m[f"{base}.nearest_raw.err_mm"])
            rows.append([pose, m[f"{base}.no_motion.err_mm"], m[f"{base}.mean.err_mm"], m[f"{base}.nearest.err_mm"],
                         m[f"{base}.oracle.err_mm"], m[f"{base}.mean_raw.err_mm"], m[f"{base}.nearest_raw.err_mm"],
                         m[f"{base}.offset_nearest.err_mm"], m[f"{base}.mean.gate"], m[f"{base}.nearest.gate"],
                         "yes" if best <= m[f"{base}.no_motion.err_mm"] else "NO",
                         "yes" if best_raw <= m[f"{base}.no_motion.err_mm"] else "NO"])
    out += ["### Corrective pairs (skinning → skinning+blendshape), err mm", "",
            _table(["pose", "no motion", "mean", "nearest", "oracle", "mean raw", "nearest raw", "offset nearest",
                    "gate mean", "gate nearest", "better of mean/nearest not worse than no motion", "raw: not worse"], rows), ""]
    if any(k.startswith("correctives.") for k in m):
        from latent_model.analysis.corrective_eval import markdown as corrective_markdown

        out += ["### Corrective fields on held-out characters in every rest: explained (worst character)", "",
                corrective_markdown(m), ""]
    out += _decoder_section(m, singles)
    if any(k.startswith("detail.") for k in m):
        from latent_model.analysis.detail_eval import markdown as detail_markdown

        out += ["## 6c. Local detail: faces and fingers", "",
                "The head and hands encoded at their own scale with co-moving samples (`lrr train detail`): latent "
                "cosine and R_cond/noise of each face and finger pose's region delta, and the transfer of the whole "
                f"mesh (neutral → pose) on {len(m.get('meta.detail_characters', []))} held-out characters over their "
                "rest configurations.", "", detail_markdown(m), ""]
        if "detail" in figs:
            out += [f"![the paper's facial figure, made by the product]({figs['detail'].name})", ""]
    out += ["## 7. Rendered predictions", "", "source | mean | nearest | truth; predictions coloured by per-vertex error.", ""]
    out += [f"![{kind} {pose}]({path.name})" for kind, pose, path in ex_figs]
    return "\n".join(out) + "\n"
