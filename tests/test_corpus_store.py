"""The built tiny corpus: layout, SDF samples, determinism, resume, pairs, CLI and bad input."""
import json
import shutil

import numpy as np
import pytest

from latent_model.cli import main as lrr
from latent_model.corpus.config import corpus_preset
from latent_model.corpus.build import build
from latent_model.corpus.pairs import enumerate_pairs
from latent_model.types import PAIR_KINDS
from latent_model.corpus.poses import get_pose
from latent_model.corpus.sdf import signed_distance
from latent_model.corpus.store import Corpus, CorpusError


def test_split_and_identities(tiny_corpus, tiny_config):
    """Persons split train / val / test; each is a bind character plus its rests' characters."""
    c, cfg = tiny_corpus, tiny_config
    bind = [s for s in c.identities if s.rest == "bind"]
    assert len(bind) == cfg.n_identities and [s.id for s in bind] == [f"id{i:03d}" for i in range(cfg.n_identities)]
    assert len(c.split_indices("test", rest="bind")) == cfg.n_test and len(c.split_indices("val", rest="bind")) == cfg.n_val
    assert len(c.identities) == cfg.n_identities + cfg.n_train_persons * cfg.train_rests + cfg.n_val \
        + cfg.n_test * len(cfg.test_rests)
    assert sum(s.stylised for s in bind if s.split == "test") == cfg.n_stylised
    assert sum(s.stylised for s in bind if s.split != "test") == cfg.n_stylised_train
    assert c.manifest["rests"] == list(c.rests) and c.manifest["generator_version"] == 4


def test_every_state_present_and_deduplicated(tiny_corpus):
    c = tiny_corpus
    n_states = len(c.identities) * (1 + 3 * len(c.poses))
    assert len(c.states) == n_states
    i = 0
    # a face-only pose's skinning state is the neutral geometry
    assert c.row(c.state(i, "browDwLf", "skinning")) == c.row(c.state(i, None, "neutral"))
    assert c.row(c.state(i, "browDwLf", "skinning_plus_blendshape")) == c.row(c.state(i, "browDwLf", "blendshape"))
    # skeletal poses own three distinct rows
    rows = {c.row(c.state(i, "elbowBentLf", v)) for v in ("skinning", "blendshape", "skinning_plus_blendshape")}
    assert len(rows) == 3


def test_stored_vertices_match_the_generator(tiny_corpus, generator):
    c = tiny_corpus
    spec = c.identities[1]
    v = c.vertices(c.state(1, "elbowBentLf", "skinning_plus_blendshape"))
    assert v.dtype == np.float32 and v.shape == (c.n_vertices, 3)
    ref = generator.state(spec, "elbowBentLf", "skinning_plus_blendshape")
    assert np.abs(v - ref).max() < 1e-5
    n = c.normals(c.state(1, None, "neutral"))
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=2e-3)


def test_sdf_signs_and_distances(tiny_corpus):
    c = tiny_corpus
    s = c.state(0, "kneeBentLf", "skinning_plus_blendshape")
    pts, vals = c.sdf(s)
    assert pts.shape == (c.config.sdf.k, 3) and vals.shape == (c.config.sdf.k,)
    verts = c.vertices(s).astype(np.float64)
    assert np.allclose(signed_distance(pts, verts, c.body_faces), vals, atol=1e-6)
    assert (vals < 0).sum() > 0.2 * len(vals) and (vals > 0).sum() > 0.2 * len(vals)
    # a point at the pelvis is inside, a point 1 m in front of the face is outside at ~1 m
    inside = signed_distance(np.array([[0.0, 0.0, 0.05]]), verts, c.body_faces)[0]
    outside = signed_distance(np.array([[0.0, -1.5, 0.6]]), verts, c.body_faces)[0]
    assert inside < -0.05 and 1.2 < outside < 1.6


def test_independent_resamplings(tiny_corpus):
    c = tiny_corpus
    s = c.state(2, None, "neutral")
    p0, _ = c.sdf(s)
    p1, v1 = c.resample_sdf(s, 1)
    p1b, _ = c.resample_sdf(s, 1)
    p2, _ = c.resample_sdf(s, 2)
    assert np.array_equal(p1, p1b)
    assert not np.allclose(p0, p1) and not np.allclose(p1, p2)


def test_same_config_same_arrays_and_resume_after_interruption(tiny_corpus, tmp_path):
    out = tmp_path / "again"
    cfg = corpus_preset("tiny")
    build(cfg, out, workers=1, stop_after=2)  # as if killed after two identities
    assert not (out / "manifest.json").exists()
    with pytest.raises(CorpusError, match="unfinished"):
        Corpus(out)
    prog = json.loads((tmp_path / "again.partial" / "progress.json").read_text())
    assert len(prog["done"]) == 2
    build(cfg, out, workers=1)  # resumes
    again = Corpus(out)
    for name in ("vertices", "sdf_points", "sdf_values", "normals"):
        assert np.array_equal(np.asarray(again.arrays[name]), np.asarray(tiny_corpus.arrays[name])), name


def test_pairs_definitions(tiny_corpus):
    c = tiny_corpus
    pairs = enumerate_pairs([0], c.poses)
    kinds = {p.kind for p in pairs}
    assert kinds == set(PAIR_KINDS)
    n2p = [p for p in pairs if p.kind == "neutral_to_pose"]
    assert len(n2p) == len(c.poses)
    corr = [p for p in pairs if p.kind == "skinning_to_skinning_plus_blendshape"]
    assert len(corr) == sum(get_pose(p).has_skeletal for p in c.poses)
    combo = [p for p in pairs if p.kind == "source_to_combo"]
    assert {(p.source[0], p.pose) for p in combo} == {("elbowBentLf", "elbowBentLf+kneeBentLf"),
                                                       ("kneeBentLf", "elbowBentLf+kneeBentLf")}
    for p in pairs:  # every pair resolves to two stored states
        c.state(p.identity, p.source[0], p.source[1])
        c.state(p.identity, p.target[0], p.target[1])


def test_shards_merge_into_the_same_corpus(tiny_corpus, tmp_path):
    cfg = corpus_preset("tiny")
    a, b = tmp_path / "s0", tmp_path / "s1"
    build(cfg, a, workers=1, shard=(0, 2))
    build(cfg, b, workers=1, shard=(1, 2))
    with pytest.raises(CorpusError, match="partial"):
        Corpus(a)
    from latent_model.corpus.build import merge

    merged = Corpus(merge([a, b], tmp_path / "merged"))
    assert np.array_equal(np.asarray(merged.arrays["vertices"]), np.asarray(tiny_corpus.arrays["vertices"]))


def test_corrupt_old_and_missing_stores_are_reported(tiny_corpus, tmp_path):
    with pytest.raises(CorpusError, match="lrr corpus build"):
        Corpus(tmp_path / "nothing")
    bad = tmp_path / "old"
    shutil.copytree(tiny_corpus.path, bad)
    m = json.loads((bad / "manifest.json").read_text())
    m["format_version"] = 0
    (bad / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CorpusError, match="format version 0"):
        Corpus(bad)
    m["format_version"] = 1
    (bad / "manifest.json").write_text(json.dumps(m))
    np.save(bad / "sdf_values.npy", np.zeros((3, 4), dtype=np.float32))  # wrong row count
    with pytest.raises(CorpusError, match="corrupt"):
        Corpus(bad)
    (bad / "manifest.json").write_text("{not json")
    with pytest.raises(CorpusError, match="unreadable"):
        Corpus(bad)


def test_bad_names_list_the_valid_ones(tiny_corpus, capsys):
    with pytest.raises(ValueError, match="tiny, standard, paper"):
        corpus_preset("huge")
    with pytest.raises(KeyError, match="elbowBentLf"):
        tiny_corpus.parse_state("id000/elbowBendLf/skinning")
    with pytest.raises(KeyError, match="id000"):
        tiny_corpus.parse_state("id999/neutral")
    with pytest.raises(KeyError, match="skinning_plus_blendshape"):
        tiny_corpus.parse_state("id000/elbowBentLf/lbs")
    assert lrr(["corpus", "export", "id000/noSuchPose/skinning", "--corpus", str(tiny_corpus.path), "-o", "x.ply"]) == 2
    assert "unknown pose" in capsys.readouterr().err


def test_cli_info_export_and_sheet(tiny_corpus, tmp_path, capsys):
    path = str(tiny_corpus.path)
    assert lrr(["corpus", "info", "--corpus", path]) == 0
    out = capsys.readouterr().out
    assert "nearest-identity distance" in out and "stature" in out and "correctives" in out
    ply = tmp_path / "x.ply"
    assert lrr(["corpus", "export", "id001/elbowBentLf/skinning", "--corpus", path, "-o", str(ply)]) == 0
    import trimesh

    m = trimesh.load(ply, process=False)
    assert np.allclose(m.vertices, tiny_corpus.vertices(tiny_corpus.parse_state("id001/elbowBentLf/skinning")), atol=1e-6)
    png = tmp_path / "sheet.png"
    assert lrr(["corpus", "sheet", "--corpus", path, "-o", str(png), "--identities", "id000",
                "--poses", "neutral,cornerUpLf"]) == 0
    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img[..., :3].std() > 0.05  # something was drawn


def test_a_killed_build_resumes_to_identical_arrays(tiny_corpus, tmp_path):
    """SIGKILL a real `lrr corpus build` mid-way, then finish it with the same command."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "latent_model.cli", "corpus", "build", "--preset", "tiny", "--out", str(out),
           "--workers", "1", "--quiet", "--brief"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    progress = tmp_path / "killed.partial" / "progress.json"
    deadline = time.time() + 300
    while time.time() < deadline:
        if progress.exists() and len(json.loads(progress.read_text() or "{}").get("done", {})) >= 1:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "manifest.json").exists()
    done_before = len(json.loads(progress.read_text())["done"])
    assert 1 <= done_before < tiny_corpus.config.n_identities
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    again = Corpus(out)
    for name in ("vertices", "sdf_values", "normals"):
        assert np.array_equal(np.asarray(again.arrays[name]), np.asarray(tiny_corpus.arrays[name])), name
    assert not (tmp_path / "killed.partial").exists()
