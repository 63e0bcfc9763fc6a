"""`lrr evaluate` end to end on the tiny preset: every section and figure, stable metric keys,
deterministic numbers."""
import json

import numpy as np
import pytest
import torch

from latent_model.bank import build_bank
from latent_model.config import preset
from latent_model.corpus.pairs import enumerate_pairs
from latent_model.types import PAIR_KINDS
from latent_model.nn.model import LatentReRig
from latent_model.checkpoint import save_checkpoint

STRATEGIES = ("mean", "nearest", "oracle", "mean_raw", "nearest_raw", "oracle_raw", "no_motion", "offset_nearest",
              "offset_mean")
STATS = ("n", "mean", "median", "std", "min", "max")


@pytest.fixture(scope="module")
def model_files(tiny_corpus, tmp_path_factory, untrained_model_moves):
    torch.manual_seed(0)
    p = preset("tiny")
    model = LatentReRig(p.model).eval()
    bank = build_bank(model, tiny_corpus, progress=False)
    untrained_model_moves(model, bank, tiny_corpus)  # motion to measure, on every pair kind
    d = tmp_path_factory.mktemp("model")
    save_checkpoint(d / "model.safetensors", model, p, "all", 0)
    bank.save(d / "bank.safetensors")
    return d / "model.safetensors", d / "bank.safetensors"


@pytest.fixture(scope="module")
def report(model_files, tiny_corpus, tmp_path_factory):
    from latent_model.analysis.report import evaluate

    out = tmp_path_factory.mktemp("report")
    evaluate(model_files[0], model_files[1], tiny_corpus.path, out, progress=False)
    return out, json.loads((out / "metrics.json").read_text())


def required_keys(corpus) -> list[str]:
    keys = []
    for pose in corpus.poses:
        keys += [f"latent.pose_consistency.{pose}.{k}" for k in ("cos_mean", "cos_std", "norm_mean")]
    for name in ("identity_distance", "noise_distance"):
        keys += [f"latent.{name}.{s}" for s in STATS]
    keys += ["latent.identity_noise_ratio", "latent.ks.D", "latent.ks.p", "latent.cond_noise.mean",
             "latent.cond_noise.median"]
    keys += [f"baseline.pca16.{k}" for k in list(keys)]
    test = corpus.split_indices("test")
    for p in enumerate_pairs(test[:1], tuple(corpus.poses), PAIR_KINDS):
        pose = f"{p.pose}@{p.source[0]}" if p.kind == "source_to_combo" else p.pose
        for s in STRATEGIES:
            keys += [f"transfer.{p.kind}.{pose}.{s}.{m}" for m in ("err_mm", "err_moving_mm", "leak_mm", "explained")]
    return keys


def test_report_has_every_section_and_figure(report):
    from PIL import Image

    out, _ = report
    md = (out / "report.md").read_text()
    for title in ("## 1. Pose consistency", "## 2-3. Identity separation", "## 4. R_cond/noise", "## 5. Identity–pose",
                  "## 6. Mesh prediction", "## 7. Rendered predictions"):
        assert title in md
    figures = [line.split("](")[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
    assert {"identity_distances.png", "pose_cosines.png", "noise_floor.png", "entanglement.png",
            "pose_consistency.png"} <= set(figures)
    assert any(f.startswith("transfer_neutral_to_pose_elbowBentLf") for f in figures)
    assert any(f.startswith("transfer_skinning_to_skinning_plus_blendshape_elbowBentLf") for f in figures)
    for f in figures:
        img = np.asarray(Image.open(out / f).convert("L"), dtype=float)
        assert img.shape[0] > 100 and img.std() > 5, f"figure {f} is blank"


def test_metrics_keys_are_stable_and_finite(report, tiny_corpus):
    _, m = report
    missing = [k for k in required_keys(tiny_corpus) if k not in m]
    assert not missing, f"missing metrics keys, e.g. {missing[:5]}"
    numbers = {k: v for k, v in m.items() if isinstance(v, float)}
    assert all(np.isfinite(v) for v in numbers.values())
    # no motion explains nothing and leaks nothing; the oracle sees the true target latent
    kind, pose = "neutral_to_pose", "elbowBentLf"
    assert m[f"transfer.{kind}.{pose}.no_motion.explained"] == 0.0
    assert m[f"transfer.{kind}.{pose}.no_motion.leak_mm"] == 0.0
    assert 0 < m["latent.identity_distance.n"] <= 190


def test_pose_consistency_is_also_reported_within_each_rest(report, tiny_corpus):
    """The paper's characters share one rest: each pose's cosine is also given among the held-out characters of
    each rest configuration, and the report's table shows it beside the one across rests."""
    out, m = report
    test = tiny_corpus.split_indices("test")
    rests = sorted({tiny_corpus.identities[i].rest for i in test})
    assert len(rests) > 1  # the tiny corpus has a held-out rest: bind and tpose
    for pose in tiny_corpus.poses:
        for rest in rests:
            v = m[f"latent.pose_consistency.{pose}.rest.{rest}.cos_mean"]
            assert -1.0 <= v <= 1.0
    assert "model cos within a rest" in (out / "report.md").read_text()


def test_latent_metrics_are_deterministic(report, model_files, tiny_corpus, tmp_path):
    from latent_model.analysis.report import evaluate

    _, first = report
    out = evaluate(model_files[0], model_files[1], tiny_corpus.path, tmp_path / "again", transfer_ids=1, progress=False)
    again = json.loads((out / "metrics.json").read_text())
    for k, v in first.items():
        if k.startswith(("latent.", "baseline.")):
            assert again[k] == pytest.approx(v, rel=1e-6, abs=1e-9), k


def test_baselines_are_kept_per_corpus_and_read_back_unchanged(tiny_corpus, tmp_path):
    """The no-learning baselines depend on the corpus alone: a second evaluation reads them from the cache, equal."""
    from latent_model.analysis.latent_space import SampleCache
    from latent_model.analysis.report import baseline_analyses

    lat, fig, cached = baseline_analyses(tiny_corpus, SampleCache(tiny_corpus), lambda _m: None, tmp_path)
    assert not cached and len(list(tmp_path.glob("baselines_*.pkl"))) == 1
    again, fig2, cached = baseline_analyses(tiny_corpus, SampleCache(tiny_corpus), lambda _m: None, tmp_path)
    assert cached and again == lat
    assert np.array_equal(fig2["pca16"]["identity_matrix"][0], fig["pca16"]["identity_matrix"][0])


def test_evaluate_refuses_a_corpus_the_checkpoint_was_not_trained_on(model_files, tiny_corpus, tmp_path):
    """A checkpoint records its corpus's digest; evaluating it against a corpus built by another
    config or generator version (e.g. after a rig fix) would score it on the wrong ground truth."""
    from latent_model.analysis.report import check_corpus_matches, evaluate
    from latent_model.corpus.config import GENERATOR_VERSION
    from latent_model.corpus.store import CorpusError
    from latent_model.checkpoint import load_checkpoint

    digest = tiny_corpus.manifest["config_digest"]
    check_corpus_matches({"extra": json.dumps({"corpus_digest": digest})}, model_files[0], tiny_corpus)
    check_corpus_matches({}, model_files[0], tiny_corpus)  # older checkpoints without the record pass
    model, p, _ = load_checkpoint(model_files[0])
    stale = tmp_path / "stale.safetensors"
    save_checkpoint(stale, model, p, "all", 0, extra={"corpus_digest": "0123456789abcdef",
                                                      "corpus_generator": GENERATOR_VERSION})
    with pytest.raises(CorpusError, match="0123456789abcdef.*lrr corpus build --preset tiny --force"):
        evaluate(stale, model_files[1], tiny_corpus.path, tmp_path / "out", progress=False)
    assert not (tmp_path / "out" / "metrics.json").exists()
    # a model of an older generator (the shipped one: v3, no record): rebuilding cannot help, say so
    save_checkpoint(stale, model, p, "all", 0, extra={"corpus_digest": "0123456789abcdef"})
    with pytest.raises(CorpusError, match=r"generator v3's corpus, this program builds v4.*--corpus"):
        evaluate(stale, model_files[1], tiny_corpus.path, tmp_path / "out", progress=False)


def test_the_mesh_transfer_shared_among_processes_gives_the_one_process_metrics(model_files, tiny_corpus):
    """`workers` = 2 splits the characters between two processes; every metric and example is the same."""
    from latent_model.analysis.transfer_eval import evaluate_transfer
    from latent_model.transfer import Transfer

    transfer = Transfer.from_files(*model_files)
    ids = tiny_corpus.split_indices("test")
    assert len(ids) >= 2
    one, ex_one = evaluate_transfer(transfer, tiny_corpus, ids, progress=False, workers=1)
    two, ex_two = evaluate_transfer(transfer, tiny_corpus, ids, progress=False, workers=2)
    assert list(two) == list(one)
    for k, v in one.items():
        assert two[k] == pytest.approx(v, rel=1e-6, abs=1e-9), k
    assert set(ex_two) == set(ex_one) and ex_one
    with pytest.raises(ValueError, match="--workers 0"):
        from latent_model.analysis.report import evaluate

        evaluate(*model_files, tiny_corpus.path, tiny_corpus.path / "never", workers=0)
    for key, figs in ex_one.items():
        for name, v in figs.items():
            np.testing.assert_allclose(ex_two[key][name], v, atol=1e-6)


def test_resamplings_are_kept_on_disk_and_read_back(tiny_corpus, tmp_path, monkeypatch):
    from latent_model.analysis.latent_space import SampleCache
    from latent_model.analysis.sample_cache import KeptSampleCache

    s = tiny_corpus.state(0, None, "neutral")
    points, values = KeptSampleCache(tiny_corpus, tmp_path).get(s, 1)
    fresh = SampleCache(tiny_corpus).get(s, 1)
    np.testing.assert_array_equal(points, fresh[0])
    np.testing.assert_array_equal(values, fresh[1])
    kept = KeptSampleCache(tiny_corpus, tmp_path)
    assert kept.path(s, 1).exists() and not kept.path(s, 2).exists()
    monkeypatch.setattr(type(tiny_corpus), "resample_sdf", lambda *a, **k: pytest.fail("re-sampled a kept state"))
    back = kept.get(s, 1)
    np.testing.assert_array_equal(back[0], points)
    np.testing.assert_array_equal(back[1], values)
    monkeypatch.undo()
    kept.path(s, 1).write_bytes(b"torn")  # an unreadable file is sampled again and rewritten
    again = KeptSampleCache(tiny_corpus, tmp_path).get(s, 1)
    np.testing.assert_array_equal(again[1], values)
    assert np.load(kept.path(s, 1))["values"].shape == values.shape
