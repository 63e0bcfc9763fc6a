"""The local detail stage (latent_model/detail.py, train/local_detail.py): `lrr train detail` on the tiny preset,
its file, and what `Transfer` does with it: a face pose moves the head only, in proportion to the magnitude, as
the delta's mix of training poses on the source's own region; a body pose is left to decoder v2; an example pair's region deltas are co-moving."""
import dataclasses

import numpy as np
import pytest

from latent_model.types import FINAL


@pytest.fixture(scope="module")
def detail(tmp_path_factory):
    from latent_model.config import preset
    from latent_model.detail import LocalDetailModel
    from latent_model.train.local_detail import detail_training, run_local_detail

    path = tmp_path_factory.mktemp("detail") / "detail.safetensors"
    cfg = dataclasses.replace(detail_training("tiny"), codec_steps=40)
    run_local_detail(preset("tiny"), cfg, path, workers=1, log=lambda _m: None)
    return path, LocalDetailModel.load(path)


@pytest.fixture(scope="module")
def with_detail(tiny_motion, detail):
    transfer, _ = tiny_motion
    return type(transfer)(transfer.model, transfer.bank, transfer.sdf_k, detail=detail[1])


def _target(tiny_corpus, transfer):
    i = tiny_corpus.split_indices("test")[0]
    s = tiny_corpus.state(i, None, "neutral")
    return i, transfer.prepare(tiny_corpus.vertices(s), tiny_corpus.faces)


def test_the_file_holds_the_networks_and_the_bank(detail, tmp_path):
    from latent_model.checkpoint import CheckpointError
    from latent_model.detail import LocalDetailModel

    path, model = detail
    assert ("browDwLf", "head") in model.bank.deltas and ("fingerKnuckleB02Lf", "hand_left") in model.bank.deltas
    assert not any(p == "elbowBentLf" for p, _ in model.bank.deltas)  # a body pose is decoder v2's
    assert set(model.bank.noise) == {"head", "hand"} and all(v > 0 for v in model.bank.noise.values())
    again = tmp_path / "again.safetensors"
    model.save(again)
    other = LocalDetailModel.load(again)
    for k, v in model.net.state_dict().items():
        assert np.array_equal(v.numpy(), other.net.state_dict()[k].numpy()), k
    assert {"head", "hand_left"} <= set(model.fields) and "browDwLf" in model.fields["head"].poses
    for r, f in model.fields.items():
        assert np.array_equal(f.values, other.fields[r].values) and f.poses == other.fields[r].poses
        assert f.values.shape == (len(f.poses), len(f.anchor), 3) and np.abs(f.values).max() > 0
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a file")
    with pytest.raises(CheckpointError, match="lrr train detail"):
        LocalDetailModel.load(bad)
    # a file of format 2 holds its hands in their former limb frames, which today's frames would misread: refused
    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(again), framework="pt") as f:
        meta, tensors = dict(f.metadata()), {k: f.get_tensor(k) for k in f.keys()}
    old = tmp_path / "format2.safetensors"
    save_file(tensors, str(old), metadata={**meta, "format": "lrr-detail-2"})
    with pytest.raises(CheckpointError, match="lrr train detail"):
        LocalDetailModel.load(old)


def test_a_face_pose_moves_the_head_only_and_scales_with_the_magnitude(with_detail, tiny_motion, tiny_corpus):
    plain, _ = tiny_motion
    _, mesh = _target(tiny_corpus, with_detail)
    regions = with_detail.regions(mesh)
    head = np.zeros(len(mesh.vertices), bool)
    head[regions.frames["head"].vertices] = True
    out = with_detail.predict_detail(mesh, "browDwLf")
    # the detail stage moves a face pose alone: the body decoder does not read it, ungated (raw) either
    assert not np.allclose(plain.predict_detail(mesh, "browDwLf").raw, mesh.vertices)  # which it would move
    added = np.linalg.norm(out.raw - mesh.vertices, axis=1)
    assert added[head].max() > 1e-4 and added[~head].max() == 0.0
    assert "head" in out.detail and 0.0 <= out.detail["head"] <= 1.0
    # no motion asked: the source exactly; the added motion is continuous and linear in the magnitude
    assert np.array_equal(with_detail.predict(mesh, "browDwLf", magnitude=0.0), mesh.vertices)
    half = with_detail.predict_detail(mesh, "browDwLf", magnitude=0.5).raw - mesh.vertices
    full = out.raw - mesh.vertices
    assert np.allclose(half, 0.5 * full, atol=2e-5)
    # a body pose: decoder v2 alone
    assert np.array_equal(with_detail.predict(mesh, "elbowBentLf"), plain.predict(mesh, "elbowBentLf"))


def test_the_detail_reads_the_delta_and_the_source_region(with_detail, tiny_corpus):
    """The displacement is the delta's mix of the training poses (a pose's mean delta reads as that pose alone, the
    sum of two as both), placed on the source's own region: another head shape moves differently."""
    from dataclasses import replace

    _, mesh = _target(tiny_corpus, with_detail)
    detail = with_detail.detail
    regions = with_detail.regions(mesh)
    moved = mesh.vertices.astype(np.float64)
    brow, cheek = detail.bank.mean("browDwLf", "head"), detail.bank.mean("puffLf", "head")
    assert detail.mix("head", brow) == pytest.approx({"browDwLf": 1.0})
    # (scaled above the noise floor: the tiny model's deltas are not, and a pose under it is dropped from a mix)
    s = 2 * detail.bank.noise["head"] / min(np.linalg.norm(brow), np.linalg.norm(cheek))
    assert detail.mix("head", s * (brow + cheek)) == pytest.approx({"browDwLf": s, "puffLf": s})
    a = detail.displacement(regions, [({"head": s * brow}, 1.0)], moved)
    b = detail.displacement(regions, [({"head": s * cheek}, 1.0)], moved)
    both = detail.displacement(regions, [({"head": s * (brow + cheek)}, 1.0)], moved)
    assert np.abs(a - b).max() > 1e-5 and np.allclose(both, a + b, atol=1e-9)
    f = regions.frames["head"]
    wider = f.to_local(moved[f.vertices]) * np.array([1.3, 1.0, 0.8])
    other = replace(regions, placed={"head": detail.fields["head"].place(wider)}, held_placed={})
    assert np.abs(detail.displacement(other, [({"head": s * brow}, 1.0)], moved) - a).max() > 1e-6


def test_an_example_pair_gives_co_moving_region_deltas(with_detail, generator, tiny_corpus):
    from latent_model.corpus.identities import IdentitySpec
    from latent_model.corpus.poses import POSES

    person = IdentitySpec("example", "train", {}, {})
    a = generator.neutral(person).astype(np.float32)
    a1 = getattr(generator.pose(person, POSES["browDwLf"]), FINAL).astype(np.float32)
    pa, pa1 = with_detail.prepare(a, generator.faces), with_detail.prepare(a1, generator.faces)
    deltas = with_detail.example_detail(pa, pa1)
    assert set(deltas) == {"head", "hand_left", "hand_right"}
    # the hands did not deform: their co-moving deltas vanish; the brow did
    assert np.linalg.norm(deltas["hand_left"]) < 1e-3 * max(np.linalg.norm(deltas["head"]), 1e-6)
    assert np.linalg.norm(deltas["head"]) > 0
    _, mesh = _target(tiny_corpus, with_detail)
    out = with_detail.predict_detail(mesh, None, delta=with_detail.example_delta(pa, pa1), detail_delta=deltas)
    assert set(out.detail) <= {"head", "hand_left", "hand_right"} and "head" in out.detail


def test_an_example_pairs_hand_is_read_from_its_own_motion(with_detail, generator, tiny_corpus):
    """A hand's fields chain: an example's hand motion is fitted through them (`RegionFields.fit`), not read from its
    latent delta; the fitted weights stand for the delta, and the prediction moves the target's hand by them."""
    from latent_model.corpus.identities import IdentitySpec
    from latent_model.corpus.poses import POSES
    from latent_model.detail import FittedDelta

    detail = with_detail.detail
    pose = detail.fields["hand_left"].poses[0]
    person = IdentitySpec("example", "train", {}, {})
    a = generator.neutral(person).astype(np.float32)
    a1 = getattr(generator.pose(person, POSES[pose]), FINAL).astype(np.float32)
    pa, pa1 = with_detail.prepare(a, generator.faces), with_detail.prepare(a1, generator.faces)
    deltas = with_detail.example_detail(pa, pa1)
    hand = deltas["hand_left"]
    assert isinstance(hand, FittedDelta) and not isinstance(deltas["head"], FittedDelta)
    assert max(detail.mix("hand_left", hand), key=detail.mix("hand_left", hand).get) == pose
    assert hand.weights[0] > 0.5 and np.allclose(hand, hand.weights @ detail.basis["hand_left"], atol=1e-5)
    assert not np.any(deltas["hand_right"])  # the other hand did not move: nothing fitted
    assert (-hand).weights is None  # an array made from it is a plain delta again
    _, mesh = _target(tiny_corpus, with_detail)
    out = with_detail.predict_detail(mesh, None, delta=with_detail.example_delta(pa, pa1), detail_delta=deltas)
    moved = np.linalg.norm(out.vertices - mesh.vertices, axis=1)
    hand_vertices = with_detail.regions(mesh).frames["hand_left"].vertices
    assert "hand_left" in out.detail and moved[hand_vertices].max() > 1e-3


def test_the_detail_evaluation_measures_the_stage(with_detail, tiny_motion, tmp_path):
    """`lrr evaluate`'s local detail section on two held-out tiny characters: every face and finger pose gets a
    latent cosine and R_cond/noise, and transfer rows per rest; a transfer without the stage measures nothing."""
    from latent_model.analysis.detail_eval import asymmetry_mm, evaluate_detail, markdown, mirror_map
    from latent_model.analysis.report import detail_characters
    from latent_model.config import preset

    p = preset("tiny")
    specs = detail_characters(p, "test", 1)
    assert [s.rest for s in specs] == ["bind", "tpose"]
    m, fig = evaluate_detail(with_detail, specs, p.corpus.pose_names(), noise_persons=1, say=lambda _m: None)
    # the characters shared between two processes: the same metrics and figure (up to rounding: a process of one
    # torch thread sums the region codes in another order, and a noise floor is the difference of two near codes)
    m2, fig2 = evaluate_detail(with_detail, specs, p.corpus.pose_names(), noise_persons=1, say=lambda _m: None,
                               workers=2)
    assert list(m2) == list(m) and all(m2[k] == pytest.approx(v, rel=1e-3, abs=1e-6) for k, v in m.items())
    np.testing.assert_allclose(fig2["example"]["mean"], fig["example"]["mean"], atol=1e-6)
    for pose in ("browDwLf", "puffLf", "cornerUpLf", "fingerKnuckleB02Lf"):
        assert -1.0 <= m[f"detail.latent.cos.{pose}"] <= 1.0 and m[f"detail.latent.cond_noise.{pose}"] > 0
        for rest in ("bind", "tpose"):
            assert np.isfinite(m[f"detail.transfer.{pose}.mean.{rest}.explained"])
    assert "detail.transfer.group.face.nearest.tpose.leak_mm" in m and "**face group**" in markdown(m)
    assert "elbowBentLf" not in " ".join(m)  # body poses are the decoder's section
    plain, _ = tiny_motion
    assert evaluate_detail(plain, specs, p.corpus.pose_names(), say=lambda _m: None) == ({}, {})
    # the paper's facial figure: mean and nearest beside the truth, on the head of the first character
    assert set(fig["example"]) == {"source", "truth", "mean", "nearest"} and fig["title"].startswith(specs[0].id)
    from latent_model.analysis.figures import detail_closeup

    png = detail_closeup(fig["example"], fig["faces"], fig["region"], fig["title"], tmp_path / "closeup.png")
    assert png.stat().st_size > 10_000
    # the asymmetry of a mirror-symmetric motion is 0, of a one-sided one its size
    v = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, 0, 1.0]])
    mirror = mirror_map(v)
    assert list(mirror) == [1, 0, 2]
    where = np.ones(3, bool)
    assert asymmetry_mm(np.array([[-0.001, 0, 0], [0.001, 0, 0], [0, 0, 0.001]]), mirror, where) == 0.0
    assert asymmetry_mm(np.array([[0, 0, 0.003], [0, 0, 0], [0, 0, 0]]), mirror, where) == pytest.approx(2.0)


def test_a_pose_made_of_face_parts_is_the_stages_alone(with_detail, tiny_motion, tiny_corpus):
    """Decoder v2 never trained on face or finger poses: with the stage, such a pose moves nothing outside its
    region (the body's gate is 0), a body pose keeps decoder v2's motion and gate; the window says what moved."""
    from explorer.results import Prediction

    plain, _ = tiny_motion
    _, mesh = _target(tiny_corpus, with_detail)
    head = np.zeros(len(mesh.vertices), bool)
    head[with_detail.regions(mesh).frames["head"].vertices] = True
    out = with_detail.predict_detail(mesh, "browDwLf")
    assert out.gate == 0.0 and np.array_equal(out.vertices[~head], mesh.vertices[~head])
    body = with_detail.predict_detail(mesh, "elbowBentLf")
    assert body.gate == plain.predict_detail(mesh, "elbowBentLf").gate and body.detail == {}
    v = out.vertices
    p = Prediction("mean_pose_delta", "mean", v, None, np.zeros(len(v)), None, out.gate, out.signal, None, out.detail)
    assert "body: no motion (local detail alone)" in p.title and "local detail: head" in p.title
    # what the head's delta read as: the pose itself, alone (the bank's mean delta of a field's pose)
    assert set(out.detail_mix) == {"head"} and max(out.detail_mix["head"], key=out.detail_mix["head"].get) == "browDwLf"
    p = Prediction("mean_pose_delta", "mean", v, None, np.zeros(len(v)), None, out.gate, out.signal, None, out.detail,
                   out.detail_mix)
    assert "head = browDwLf" in p.title


def test_a_combination_adding_face_poses_to_its_posed_part_moves_them_by_the_stage(with_detail, tiny_corpus):
    """source_to_combo: what browDwLf+browDwRt adds to its posed browDwRt is browDwLf's local detail (the body decoder
    moves none of it); what a fist adds to a bent elbow is its knuckles' local detail, on the left hand alone.
    (The tiny corpus has no such keys: they are made here of a body key's deltas, which the body decoder ignores.)"""
    from latent_model.detail import LocalDetailModel

    t = with_detail
    body_key = next(p for p in t.bank.poses("source_to_combo"))
    fake = {("source_to_combo", k): t.bank.deltas[("source_to_combo", body_key)]
            for k in ("browDwLf+browDwRt<browDwRt", "elbowBentLf+fistLf<elbowBentLf")}
    # the tiny model's region deltas sit under its noise floors (gated to nothing): floors lowered to see the motion
    d = t.detail
    detail = LocalDetailModel(d.net, dataclasses.replace(d.bank, noise={k: 1e-3 * v for k, v in d.bank.noise.items()}),
                              d.fields)
    face = type(t)(t.model, dataclasses.replace(t.bank, deltas={**t.bank.deltas, **fake}), t.sdf_k, detail=detail)
    _, mesh = _target(tiny_corpus, face)
    head = np.zeros(len(mesh.vertices), bool)
    head[face.regions(mesh).frames["head"].vertices] = True
    out = face.predict_detail(mesh, "browDwLf+browDwRt<browDwRt", kind="source_to_combo")
    assert out.gate == 0.0 and out.note is None and "head" in out.detail
    moved = np.linalg.norm(out.vertices - mesh.vertices, axis=1)
    assert moved[head].max() > 1e-4 and moved[~head].max() == 0.0
    assert np.array_equal(out.vertices, face.predict(mesh, "browDwLf"))  # the added pose's own local detail
    fist = face.predict_detail(mesh, "elbowBentLf+fistLf<elbowBentLf", kind="source_to_combo")
    hand = np.zeros(len(mesh.vertices), bool)
    hand[face.regions(mesh).frames["hand_left"].vertices] = True
    moved = np.linalg.norm(fist.vertices - mesh.vertices, axis=1)
    assert fist.gate == 0.0 and fist.note is None and "hand_left" in fist.detail
    assert moved[hand].max() > 1e-4 and moved[~hand].max() == 0.0
    # each added knuckle read as itself (the tiny stage holds one of the twelve: fingerKnuckleB02Lf)
    assert np.array_equal(fist.vertices, face.predict(mesh, "fingerKnuckleB02Lf"))


def test_a_fist_reads_its_knuckles_one_by_one(with_detail, tiny_corpus):
    """neutral_to_pose of a combination of finger poses: the hand moves by each knuckle's own region delta (their
    turns compose along each finger), not by the fist's, which the hand's code reads as other knuckles; the body
    decoder adds nothing. (Made here: the tiny corpus has no fist; its stage holds one knuckle.)"""
    from latent_model.detail import LocalDetailModel

    t, d = with_detail, with_detail.detail
    knuckle = ("fingerKnuckleB02Lf", "hand_left")
    deltas = {**d.bank.deltas, ("fistLf", "hand_left"): 3.0 * d.bank.deltas[knuckle][:, ::-1].copy()}
    bank = dataclasses.replace(d.bank, deltas=deltas, noise={k: 1e-3 * v for k, v in d.bank.noise.items()})
    fist = type(t)(t.model, dataclasses.replace(t.bank, deltas={
        **t.bank.deltas, ("neutral_to_pose", "fistLf"): t.bank.deltas[("neutral_to_pose", "fingerKnuckleB02Lf")]}),
        t.sdf_k, detail=LocalDetailModel(d.net, bank, d.fields))
    _, mesh = _target(tiny_corpus, fist)
    out = fist.predict_detail(mesh, "fistLf")
    assert out.gate == 0.0 and out.detail_mix["hand_left"] == pytest.approx({"fingerKnuckleB02Lf": 1.0})
    assert np.array_equal(out.vertices, fist.predict(mesh, "fingerKnuckleB02Lf"))
    # the fist's own delta would have read otherwise
    assert fist.detail.mix("hand_left", fist.detail.pose_deltas("fistLf")[0]["hand_left"]) != out.detail_mix["hand_left"]
