"""The decoder's targets beyond the per-pose tables (issue 18), through the Transfer API, on test characters:

- ``rests``: the broad body poses, mean and nearest delta, per rest configuration (bind and each held-out rest);
- ``blend``: pose A -> pose B in 0.05 steps: the largest step against the median step, and at 0.5 how much of
  each pose's true motion its region makes;
- ``magnitude``: elbowBentLf's delta at magnitude 2 against the rig's 97 degree elbow (elbowSuperBentLf), at 0.5
  against the rig's 23.5 degrees;
- ``examples``: transfer from an example pair (`corpus/examples.py`: amplitudes, unseen combinations, unseen
  joints), the pair made on one test person, judged on the others.
Flat metrics `decoder.<analysis>....` for metrics.json; `markdown(m)` renders their tables.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from latent_model.analysis.metrics import edge_strain, mesh_errors
from latent_model.analysis.parallel import Batch, Workers, submit_characters
from latent_model.corpus.poses import JointRotation, PoseConfig
from latent_model.corpus.store import Corpus
from latent_model.detail import describe_mix
from latent_model.surface_cache import state_features
from latent_model.transfer import READ_MIN
from latent_model.types import FINAL

BROAD = ("elbowBentLf", "elbowBentRt", "kneeBentLf", "kneeBentRt", "clavicleDownwardLf", "shoulderRaiseLf",
         "shoulderForwardRt", "hipFlexLf", "wristFlexLf", "spineTwistLf", "neckTurnLf", "spineBendFw")
BLENDS = (("elbowBentLf", "kneeBentLf"), ("shoulderRaiseLf", "hipFlexRt"), ("neckTurnLf", "elbowBentRt"))
REGION_MM = 10.0  # a blend region: the vertices a pose truly moves by more than this
SCALES = (1.15, 1.3)  # the bind characters scaled up about their centre: should be flagged out of distribution
HALF_ELBOW = PoseConfig("elbow23.5Lf", "body", joints=(JointRotation("lowerarm01.L", "hinge", 23.5),))


class Characters:
    """Prepared meshes (Transfer.prepare, latent from the corpus's stored samples) of corpus characters; their
    surface features kept in `surface_cache` when given (`surface_cache.state_features`)."""

    def __init__(self, transfer, corpus: Corpus, surface_cache: Path | None = None) -> None:
        self.t, self.c, self.surface_cache = transfer, corpus, surface_cache
        self._m: dict[int, object] = {}

    def neutral(self, i: int):
        from latent_model.encoding import encode_states

        if i not in self._m:
            s = self.c.state(i, None, "neutral")
            mu = encode_states(self.t.model, self.c, [s], self.t.device)[0]
            surface = None if self.surface_cache is None else state_features(self.c, s, self.surface_cache)
            self._m[i] = self.t.prepare(self.c.vertices(s), self.c.faces, sdf_faces=self.c.body_faces, mu=mu,
                                        surface=surface)
        return self._m[i]

    def truth(self, i: int, pose: str) -> np.ndarray:
        return self.c.vertices(self.c.state(i, pose, FINAL))


def _errors(pred: np.ndarray, truth: np.ndarray, src: np.ndarray, faces: np.ndarray) -> dict[str, float]:
    return {**mesh_errors(pred, truth, src), "strain": edge_strain(pred, truth, src, faces)}


def _mean(rows: list[dict], prefix: str, out: dict) -> None:
    for k in rows[0]:
        out[f"{prefix}.{k}"] = float(np.mean([r[k] for r in rows]))


def _rest_rows(transfer, chars: Characters, i: int, poses: tuple[str, ...]) -> dict[tuple[str, str], list[dict]]:
    """{(pose | "all", mean | nearest): [errors]} of character i's broad poses."""
    c, rows = chars.c, {}
    mesh = chars.neutral(i)
    for p in poses:
        truth = chars.truth(i, p)
        for strat, name in (("mean_pose_delta", "mean"), ("nearest_identity_delta", "nearest")):
            e = _errors(transfer.predict(mesh, p, strat), truth, mesh.vertices, c.faces)
            rows.setdefault((p, name), []).append(e)
            rows.setdefault(("all", name), []).append(e)
    return rows


def _rest_summary(by_rest: dict[str, list[dict]]) -> dict:
    """decoder.rests.<rest>.<pose|all>.<mean|nearest>.<metric> from each rest's characters' `_rest_rows`."""
    out = {}
    for rest, parts in by_rest.items():
        rows: dict[tuple[str, str], list[dict]] = {}
        for part in parts:
            for key, r in part.items():
                rows.setdefault(key, []).extend(r)
        for (p, name), r in rows.items():
            _mean(r, f"decoder.rests.{rest}.{p}.{name}", out)
        out[f"decoder.rests.{rest}.characters"] = len(parts)
    return out


def _broad(chars: Characters, poses: tuple[str, ...] = BROAD) -> tuple[str, ...]:
    return tuple(p for p in poses if p in chars.c.poses)


def rest_transfer(transfer, chars: Characters, ids: list[int], poses: tuple[str, ...] = BROAD) -> dict:
    """decoder.rests.<rest>.<pose|all>.<mean|nearest>.<metric> over the test characters of each rest."""
    by_rest: dict[str, list[dict]] = {}
    for i in ids:
        by_rest.setdefault(chars.c.identities[i].rest, []).append(_rest_rows(transfer, chars, i, _broad(chars, poses)))
    return _rest_summary(by_rest)


def region_fraction(pred: np.ndarray, truth: np.ndarray, src: np.ndarray) -> float:
    """How much of the true motion of a pose's region (true displacement > REGION_MM) the prediction makes,
    projected on the truth: 1 = all of it, 0 = none."""
    d = truth - src
    region = np.linalg.norm(d, axis=1) * 1000 > REGION_MM
    t, p = d[region], (pred - src)[region]
    return float((p * t).sum() / max(float((t * t).sum()), 1e-12))


def _blends(chars: Characters, blends=BLENDS) -> list[tuple[str, str]]:
    return [(a, b) for a, b in blends if a in chars.c.poses and b in chars.c.poses]


def _blend_row(transfer, chars: Characters, i: int, a: str, b: str, steps: int = 21) -> tuple[float, float, float, float]:
    """(largest step / median step, largest step mm, fraction of A's region at 0.5, of B's) of character i's sweep."""
    mesh = chars.neutral(i)
    sweep = [transfer.predict(mesh, a, pose_b=b, blend=float(x)) for x in np.linspace(0, 1, steps)]
    moves = np.array([np.linalg.norm(y - x, axis=1).max() for x, y in zip(sweep, sweep[1:])]) * 1000
    half = sweep[steps // 2]
    return (float(moves.max() / max(np.median(moves), 1e-9)), float(moves.max()),
            region_fraction(half, chars.truth(i, a), mesh.vertices), region_fraction(half, chars.truth(i, b), mesh.vertices))


def _blend_summary(rows: dict[tuple[str, str], list[tuple]]) -> dict:
    """decoder.blend.<A>><B>.{step_ratio, step_max_mm, half_A, half_B}: the worst character's step ratio
    (largest step / median step of the sweep), the mean step, the mean fractions at 0.5."""
    out = {}
    for (a, b), r in rows.items():
        ratios, largest, half_a, half_b = (list(x) for x in zip(*r))
        key = f"decoder.blend.{a}>{b}"
        out.update({f"{key}.step_ratio": max(ratios), f"{key}.step_ratio_median": float(np.median(ratios)),
                    f"{key}.step_max_mm": max(largest), f"{key}.half_a": float(np.mean(half_a)),
                    f"{key}.half_b": float(np.mean(half_b))})
    return out


def blend_steps(transfer, chars: Characters, ids: list[int], blends=BLENDS, steps: int = 21) -> dict:
    """`_blend_summary` of every blend over the characters `ids`."""
    return _blend_summary({(a, b): [_blend_row(transfer, chars, i, a, b, steps) for i in ids]
                           for a, b in _blends(chars, blends)})


def _magnitude_rows(transfer, chars: Characters, i: int, generator) -> dict[str, dict]:
    """{"x2", "x0.5": errors} of character i: elbowBentLf's mean delta at magnitude 2 against the rig's 97 degree
    elbow (elbowSuperBentLf), at 0.5 against the rig's 23.5 degrees."""
    mesh = chars.neutral(i)
    half = getattr(generator.pose(chars.c.identities[i], HALF_ELBOW), FINAL).astype(np.float32)
    return {name: _errors(transfer.predict(mesh, "elbowBentLf", magnitude=m), truth, mesh.vertices, chars.c.faces)
            for name, m, truth in (("x2", 2.0, chars.truth(i, "elbowSuperBentLf")), ("x0.5", 0.5, half))}


def _magnitude_summary(parts: list[dict]) -> dict:
    out: dict = {}
    for name in ("x2", "x0.5"):
        _mean([p[name] for p in parts], f"decoder.magnitude.{name}", out)
    return out


def magnitude_truths(transfer, chars: Characters, ids: list[int], generator) -> dict:
    """decoder.magnitude.{x2, x0.5}.<metric> over the characters `ids` (`_magnitude_rows`)."""
    return _magnitude_summary([_magnitude_rows(transfer, chars, i, generator) for i in ids])


def _example_pairs(transfer, chars: Characters, ids: list[int], generator, examples=None) -> list[tuple]:
    """[(name, kind, (delta (Z,), body reading), {identity id: truth (V, 3)})]: each example made on the first test
    person (the user's pair, prepared like a user's meshes: its latent delta and what its body motion reads as,
    `Transfer.example_body`), its truth on the others."""
    from latent_model.corpus.examples import EXAMPLES, example_pair

    c, out = chars.c, []
    specs = [c.identities[i] for i in ids]
    for name in examples or EXAMPLES:
        pair = example_pair(generator, specs, name, specs[0].rest)
        a = transfer.prepare(pair.source_neutral, c.faces, sdf_faces=c.body_faces)
        a1 = transfer.prepare(pair.source_deformed, c.faces, sdf_faces=c.body_faces)
        out.append((name, pair.example.kind, (transfer.example_delta(a, a1), transfer.example_body(a, a1)),
                    {s.id: pair.targets[s.id][1] for s in specs[1:]}))
    return out


def _example_row(transfer, chars: Characters, i: int, read: tuple, truth: np.ndarray) -> dict:
    """Character i's errors transferring an example pair read as (delta, body reading) (`_example_pairs`)."""
    mesh = chars.neutral(i)
    delta, body = read
    return _errors(transfer.predict(mesh, None, delta=delta, body_reading=body), truth, mesh.vertices, chars.c.faces)


def _example_summary(pairs: list[tuple], rows: dict[str, list[dict]]) -> dict:
    out: dict = {}
    for name, kind, (_, body), _ in pairs:
        _mean(rows[name], f"decoder.examples.{name}", out)
        out[f"decoder.examples.{name}.kind"] = kind
        if body is not None:  # what the pair read as on its own mesh, and whether the prediction moved by it
            out[f"decoder.examples.{name}.read_explained"] = body.explained
            out[f"decoder.examples.{name}.read_used"] = bool(body.used)
            out[f"decoder.examples.{name}.read_as"] = describe_mix(body.weights) if body.weights else "no pose"
    return out


def example_transfer(transfer, chars: Characters, ids: list[int], generator, examples=None) -> dict:
    """decoder.examples.<name>.<metric>: each example made on the first test person and transferred to the others'
    neutral meshes, against the rig's truth on them."""
    pairs = _example_pairs(transfer, chars, ids, generator, examples)
    return _example_summary(pairs, {name: [_example_row(transfer, chars, i, delta, truth[chars.c.identities[i].id])
                                           for i in ids[1:]] for name, _, delta, truth in pairs})


def _novelty_row(transfer, chars: Characters, i: int, scales: tuple[float, ...] = ()) -> tuple[float, list[bool]]:
    """(character i's latent distance to the training states, whether it is flagged scaled up by each of `scales`
    about its centre)."""
    mesh = chars.neutral(i)
    v = mesh.vertices
    centre = v.mean(axis=0)
    return transfer.novelty(mesh).distance, [
        transfer.novelty(transfer.prepare((v - centre) * s + centre, chars.c.faces, sdf_faces=chars.c.body_faces)
                         ).out_of_distribution for s in scales]


def _novelty_summary(threshold: float, distances: list[float], flags: list[list[bool]], scales) -> dict:
    """decoder.novelty.*: the bank's out-of-distribution threshold, the test characters' distances to the
    training states and how many are flagged, and how many of the bind ones scaled up about their centre are."""
    d = distances
    out = {"decoder.novelty.threshold": float(threshold), "decoder.novelty.test_max": float(max(d)),
           "decoder.novelty.test_median": float(np.median(d)),
           "decoder.novelty.test_flagged": int(sum(x > threshold for x in d)) if threshold else 0,
           "decoder.novelty.test_n": len(d)}
    for k, s in enumerate(scales):
        out[f"decoder.novelty.scaled_{s:g}_flagged"] = int(sum(f[k] for f in flags))
    out["decoder.novelty.scaled_n"] = len(flags)
    return out


def novelty_check(transfer, chars: Characters, ids: list[int], bind: list[int], scales=SCALES) -> dict:
    """`_novelty_summary` of the characters `ids`, the `bind` ones also scaled."""
    rows = [_novelty_row(transfer, chars, i, scales if i in bind else ()) for i in ids]
    return _novelty_summary(transfer.bank.ood_threshold, [d for d, _ in rows], [f for _, f in rows if f], scales)


def _character(transfer, corpus: Corpus, shared: tuple, item: tuple) -> dict:
    """Every analysis of one test character (the bind ones: also blends, magnitudes, example pairs, scaled)."""
    from latent_model.corpus.build import generator

    poses, blends, magnitudes, surface_cache = shared
    i, bind, examples = item  # examples: [(name, delta, truth)] to judge on this character
    chars = Characters(transfer, corpus, surface_cache)
    out: dict = {"rest": _rest_rows(transfer, chars, i, poses)}
    if bind:
        out["blend"] = {ab: _blend_row(transfer, chars, i, *ab) for ab in blends}
        if magnitudes:
            out["magnitude"] = _magnitude_rows(transfer, chars, i, generator())
        out["examples"] = {name: _example_row(transfer, chars, i, delta, truth) for name, delta, truth in examples}
    out["novelty"] = _novelty_row(transfer, chars, i, SCALES if bind else ())
    return out


def evaluate_decoder(transfer, corpus: Corpus, ids: list[int], say: Callable[[str], None] = lambda _: None,
                     workers: "int | Workers" = 1, surface_cache: Path | None = None) -> dict:
    """Every analysis above on the test characters `ids` (rests: all of them; the others: those in bind).
    `workers`: processes sharing the characters (`parallel.submit_characters`: a count or a running `Workers`; the
    same metrics); `surface_cache`: where the characters' surface features are kept (None: computed)."""
    return submit_decoder(transfer, corpus, ids, say, workers, surface_cache).get()


def submit_decoder(transfer, corpus: Corpus, ids: list[int], say: Callable[[str], None] = lambda _: None,
                   workers: "int | Workers" = 1, surface_cache: Path | None = None) -> Batch:
    """`evaluate_decoder`'s characters queued on `workers` (the example pairs made here first), the bind ones
    first (they also sweep blends, magnitudes and example pairs: the queue ends on the short ones); `get()`
    returns its metrics."""
    from latent_model.corpus.build import generator

    chars = Characters(transfer, corpus)
    bind = [i for i in ids if corpus.identities[i].rest == "bind"]
    magnitudes = {"elbowBentLf", "elbowSuperBentLf"} <= set(corpus.poses)
    pairs = _example_pairs(transfer, chars, bind, generator()) if len(bind) >= 2 else []
    order = sorted(ids, key=lambda i: i not in bind)
    items = [(i, i in bind, [(name, delta, truth[corpus.identities[i].id]) for name, _, delta, truth in pairs
                             if i in bind[1:]]) for i in order]
    say(f"decoder: broad poses in every rest ({len(ids)} characters), blends, magnitudes, "
        f"{len(pairs)} example pairs, out-of-distribution check")

    def summary(done: list[dict]) -> dict:
        parts = [done[order.index(i)] for i in ids]  # back in the characters' order: the same sums
        by_rest: dict[str, list[dict]] = {}
        for i, part in zip(ids, parts):
            by_rest.setdefault(corpus.identities[i].rest, []).append(part["rest"])
        out = _rest_summary(by_rest)
        binds = [p for p in parts if "blend" in p]
        out.update(_blend_summary({ab: [p["blend"][ab] for p in binds] for ab in _blends(chars)}))
        if magnitudes:
            out.update(_magnitude_summary([p["magnitude"] for p in binds]))
        if pairs:
            out.update(_example_summary(pairs, {name: [p["examples"][name] for p in binds if name in p["examples"]]
                                                for name, _, _, _ in pairs}))
        out.update(_novelty_summary(transfer.bank.ood_threshold, [p["novelty"][0] for p in parts],
                                    [p["novelty"][1] for p in binds], SCALES))
        return out

    return submit_characters(_character, items, transfer, workers, corpus,
                             (_broad(chars), _blends(chars), magnitudes, surface_cache), summary)


def _f(v: float, digits: int = 2) -> str:
    return f"{v:.{digits}f}"


def markdown(m: dict) -> str:
    """The decoder's tables (empty when the metrics have none)."""
    lines: list[str] = []
    rests = sorted({k.split(".")[2] for k in m if k.startswith("decoder.rests.")}, key=lambda r: (r != "bind", r))
    if rests:
        lines += ["### Broad body poses by rest configuration (mean delta / nearest identity)", "",
                  "| rest | characters | explained (mean) | leak mm | edge strain % | explained (nearest) |",
                  "|---|---|---|---|---|---|"]
        for r in rests:
            k = f"decoder.rests.{r}.all"
            lines.append(f"| {r} | {m[f'decoder.rests.{r}.characters']} | {_f(m[f'{k}.mean.explained'])} | "
                         f"{_f(m[f'{k}.mean.leak_mm'])} | {_f(m[f'{k}.mean.strain'], 1)} | {_f(m[f'{k}.nearest.explained'])} |")
        lines.append("")
    blends = sorted({k.rsplit(".", 1)[0] for k in m if k.startswith("decoder.blend.")})
    if blends:
        lines += ["### Pose blends in 0.05 steps", "",
                  "| A → B | largest / median step (worst character) | largest step mm | A's region at 0.5 | B's at 0.5 |",
                  "|---|---|---|---|---|"]
        for b in blends:
            lines.append(f"| {b.split('.', 2)[2].replace('>', ' → ')} | {_f(m[f'{b}.step_ratio'])} | "
                         f"{_f(m[f'{b}.step_max_mm'], 1)} | {_f(m[f'{b}.half_a'])} | {_f(m[f'{b}.half_b'])} |")
        lines.append("")
    if "decoder.magnitude.x2.explained" in m:
        lines += ["### Magnitude against the rig", "", "| elbowBentLf delta | truth | explained | leak mm | edge strain % |",
                  "|---|---|---|---|---|"]
        for name, truth in (("x2", "elbowSuperBentLf (97°)"), ("x0.5", "the rig's 23.5°")):
            k = f"decoder.magnitude.{name}"
            lines.append(f"| {name} | {truth} | {_f(m[f'{k}.explained'])} | {_f(m[f'{k}.leak_mm'])} | {_f(m[f'{k}.strain'], 1)} |")
        lines.append("")
    examples = sorted({k.split(".")[2] for k in m if k.startswith("decoder.examples.")})
    if examples:
        lines += ["### Transfer from an example pair (outside the vocabulary)", "",
                  "The pair's body motion is read as a mix of the vocabulary's body poses on the example's own mesh "
                  "(`Transfer.example_body`); where the mix makes at least "
                  f"{READ_MIN:g} of it there, the targets move by those poses' motions, else the decoder reads the "
                  "pair's latent delta.", "",
                  "| example | kind | explained | leak mm | edge strain % | read as (makes on the example) | moved by |",
                  "|---|---|---|---|---|---|---|"]
        for e in examples:
            k = f"decoder.examples.{e}"
            read = (f"{m[f'{k}.read_as']} ({_f(m[f'{k}.read_explained'])})", "the read" if m[f"{k}.read_used"]
                    else "latent delta") if f"{k}.read_as" in m else ("—", "latent delta")
            lines.append(f"| {e} | {m[f'{k}.kind']} | {_f(m[f'{k}.explained'])} | {_f(m[f'{k}.leak_mm'])} | "
                         f"{_f(m[f'{k}.strain'], 1)} | {read[0]} | {read[1]} |")
        lines.append("")
    if "decoder.novelty.threshold" in m and m["decoder.novelty.threshold"] > 0:
        lines += ["### Out-of-distribution warning", "",
                  f"Threshold {m['decoder.novelty.threshold']:.2f} (standardised latent distance to the nearest training "
                  f"state; the farthest validation character's). Test characters: median {m['decoder.novelty.test_median']:.2f}, "
                  f"max {m['decoder.novelty.test_max']:.2f}, flagged {m['decoder.novelty.test_flagged']} of "
                  f"{m['decoder.novelty.test_n']}. Bind test characters scaled up about their centre, flagged: "
                  + ", ".join(f"×{k.split('_')[1]}: {v} of {m['decoder.novelty.scaled_n']}" for k, v in m.items()
                              if k.startswith("decoder.novelty.scaled_") and k.endswith("_flagged")) + ".", ""]
    return "\n".join(lines)
