"""The local detail stage (latent_model/detail.py, train/local_detail.py): `lrr train detail` on the tiny preset,
its file, and what `Transfer` does with it: a face pose moves the head only, in proportion to the magnitude, from
the source's own region code; a body pose is left to decoder v2; an example pair's region deltas are co-moving."""
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
    cfg = dataclasses.replace(detail_training("tiny"), codec_steps=40, decoder_steps=150)
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
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a file")
    with pytest.raises(CheckpointError, match="lrr train detail"):
        LocalDetailModel.load(bad)


def test_a_face_pose_moves_the_head_only_and_scales_with_the_magnitude(with_detail, tiny_motion, tiny_corpus):
    plain, _ = tiny_motion
    _, mesh = _target(tiny_corpus, with_detail)
    regions = with_detail.regions(mesh)
    head = np.zeros(len(mesh.vertices), bool)
    head[regions.frames["head"].vertices] = True
    out = with_detail.predict_detail(mesh, "browDwLf")
    added = np.linalg.norm(out.raw - plain.predict_detail(mesh, "browDwLf").raw, axis=1)
    assert added[head].max() > 1e-4 and added[~head].max() == 0.0
    assert "head" in out.detail and 0.0 <= out.detail["head"] <= 1.0
    # no motion asked: the source exactly; the added motion is continuous and linear in the magnitude
    assert np.array_equal(with_detail.predict(mesh, "browDwLf", magnitude=0.0), mesh.vertices)
    half = with_detail.predict_detail(mesh, "browDwLf", magnitude=0.5).raw - plain.predict_detail(mesh, "browDwLf", magnitude=0.5).raw
    full = out.raw - plain.predict_detail(mesh, "browDwLf").raw
    assert np.allclose(half, 0.5 * full, atol=2e-5)
    # a body pose: decoder v2 alone
    assert np.array_equal(with_detail.predict(mesh, "elbowBentLf"), plain.predict(mesh, "elbowBentLf"))


def test_the_detail_reads_the_source_region_code(with_detail, tiny_corpus):
    from latent_model.detail import MeshRegions

    _, mesh = _target(tiny_corpus, with_detail)
    regions = with_detail.regions(mesh)
    d, _ = with_detail.detail.pose_deltas("browDwLf")
    moved = mesh.vertices.astype(np.float64)
    a = with_detail.detail.displacement(regions, [(d, 1.0)], moved)
    other = MeshRegions(regions.frames, {r: c + 1.0 for r, c in regions.codes.items()}, regions.vertices,
                        regions.sdf_faces, regions.seed)
    b = with_detail.detail.displacement(other, [(d, 1.0)], moved)
    assert np.abs(a - b).max() > 1e-6


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
