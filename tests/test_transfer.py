"""Latent bank and the Transfer API (mechanics, on an untrained tiny model)."""
import dataclasses

import numpy as np
import pytest
import torch

from latent_model.bank import BankError, LatentBank, build_bank
from latent_model.encoding import encode_states
from latent_model.config import preset
from latent_model.nn.model import LatentReRig
from latent_model.transfer import Transfer, parse_strategy


def held_out_neutral(t: Transfer, c, **kw):
    """(state, prepared mesh) of the first held-out identity's neutral."""
    s = c.state(c.split_indices("test")[0], None, "neutral")
    return s, t.prepare(c.vertices(s), c.faces, sdf_faces=c.body_faces, **kw)


@pytest.fixture(scope="module")
def setup(tiny_corpus, tmp_path_factory, untrained_model_moves):
    torch.manual_seed(0)
    p = preset("tiny")
    # the pose fields' and the network's mechanics: a model without decoder v2, as the corpus-v3 one
    # (tests/test_motion.py and test_example_transfer.py test the Transfer with it)
    p = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=dataclasses.replace(p.model.motion, enabled=False)))
    model = LatentReRig(p.model).eval()
    bank = build_bank(model, tiny_corpus, progress=False)
    untrained_model_moves(model, bank, tiny_corpus)
    path = tmp_path_factory.mktemp("bank") / "bank.safetensors"
    bank.save(path)
    return p, model, bank, path


def test_bank_contents(setup, tiny_corpus):
    p, model, bank, _ = setup
    c = tiny_corpus
    train = c.split_indices("train")
    assert len(bank.keys) == sum(int(s[0]) in train for s in c.states)
    ids, d = bank.delta("neutral_to_pose", "elbowBentLf")
    assert ids == [c.identities[i].id for i in train]
    # a delta is exactly mu(target) - mu(source) of the stored states
    i = train[0]
    mu = encode_states(model, c, [c.state(i, None, "neutral"), c.state(i, "elbowBentLf", "skinning_plus_blendshape")])
    assert np.allclose(d[0], mu[1] - mu[0], atol=1e-5)
    assert np.allclose(bank.mean_delta("neutral_to_pose", "elbowBentLf"), d.mean(0))
    assert ("source_to_combo", "elbowBentLf+kneeBentLf<kneeBentLf") in bank.deltas


def test_nearest_identity_is_the_nearest(setup):
    _, _, bank, _ = setup
    ids, _ = bank.delta("neutral_to_pose", "kneeBentLf")
    src = bank.sources[("neutral_to_pose", "kneeBentLf")]
    for k, ident in enumerate(ids):
        got, d = bank.nearest_identity("neutral_to_pose", "kneeBentLf", src[k] + 1e-7)
        assert got == ident and np.array_equal(d, bank.identity_delta("neutral_to_pose", "kneeBentLf", ident))


def test_bank_round_trip_and_bad_files(setup, tmp_path):
    _, _, bank, path = setup
    again = LatentBank.load(path)
    assert np.array_equal(again.mu, bank.mu) and again.keys == bank.keys
    for key in bank.deltas:
        assert again.deltas[key][0] == bank.deltas[key][0]
        assert np.array_equal(again.deltas[key][1], bank.deltas[key][1])
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"garbage")
    with pytest.raises(BankError, match="corrupt"):
        LatentBank.load(bad)
    with pytest.raises(BankError, match="does not exist"):
        LatentBank.load(tmp_path / "nope.safetensors")
    with pytest.raises(KeyError, match="elbowBentLf"):
        bank.delta("neutral_to_pose", "elbowBent")


def test_transfer_strategies_sliders_and_errors(setup, tiny_corpus):
    """Strategies and sliders change the prediction. The noise gate is off here (`test_noise_gate`
    tests it): an untrained encoder's deltas may all lie under its floor."""
    p, model, bank, _ = setup
    c = tiny_corpus
    t = Transfer(model, dataclasses.replace(bank, noise_floor=0.0), c.config.sdf.k)
    test_id = c.split_indices("test")[0]
    s, mesh = held_out_neutral(t, c)
    outs = {}
    for strategy in ("mean", "nearest", f"identity:{bank.delta('neutral_to_pose', 'kneeBentLf')[0][0]}"):
        outs[strategy] = t.predict(mesh, "kneeBentLf", strategy)
        assert outs[strategy].shape == (c.n_vertices, 3) and np.isfinite(outs[strategy]).all()
    assert np.array_equal(outs["mean"], t.predict(mesh, "kneeBentLf", "mean_pose_delta"))  # deterministic
    target_mu = encode_states(model, c, [c.state(test_id, "kneeBentLf", "skinning_plus_blendshape")])[0]
    oracle = t.predict(mesh, "kneeBentLf", "oracle", oracle_target_mu=target_mu)
    assert not np.array_equal(oracle, outs["mean"])
    # the sliders change the prediction
    assert not np.allclose(t.predict(mesh, "kneeBentLf", magnitude=2.0), outs["mean"])
    assert not np.allclose(t.predict(mesh, "kneeBentLf", pose_b="browDwLf", blend=0.5), outs["mean"])
    with pytest.raises(ValueError, match="oracle"):
        t.predict(mesh, "kneeBentLf", "oracle")
    with pytest.raises(ValueError, match="mean_pose_delta"):
        parse_strategy("median")
    with pytest.raises(KeyError, match="kneeBentLf"):
        t.predict(mesh, "kneeBentLeft")
    with pytest.raises(ValueError, match="blend"):
        t.predict(mesh, "kneeBentLf", pose_b="browDwLf", blend=1.5)
    bad = c.vertices(s).copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        t.prepare(bad, c.faces)


def test_transfer_on_another_topology(setup, tiny_corpus):
    """Any mesh: a decimated-looking subset mesh (other vertex count) goes through the same path."""
    import trimesh

    p, model, bank, _ = setup
    c = tiny_corpus
    t = Transfer(model, bank, c.config.sdf.k)
    s = c.state(c.split_indices("test")[0], None, "neutral")
    body = trimesh.Trimesh(c.vertices(s), c.body_faces, process=True)
    sub = body.subdivide()  # 4x the faces, new vertex count and order
    mesh = t.prepare(sub.vertices, sub.faces)
    out = t.predict(mesh, "elbowBentLf", "nearest")
    assert out.shape == (len(sub.vertices), 3) and np.isfinite(out).all()


def test_cached_mesh_features_change_nothing(setup, tiny_corpus):
    """The per-mesh caches (for slider speed) give exactly the uncached output, for the pose fields
    alone (neutral_to_pose) and for the network (a corrective pair)."""
    from latent_model.nn.delta import normalised_delta
    from latent_model.types import PAIR_KINDS

    p, model, bank, _ = setup
    c = tiny_corpus
    t = Transfer(model, bank, p.corpus.sdf.k)
    fields, vd = model.pose_fields, model.vertex_decoder
    for kind, variant in (("neutral_to_pose", None), ("skinning_to_skinning_plus_blendshape", "skinning")):
        i = c.split_indices("test")[0]
        s = c.state(i, None, "neutral") if variant is None else c.state(i, "elbowBentLf", variant)
        mesh = t.prepare(c.vertices(s), c.faces, sdf_faces=c.body_faces, mu=encode_states(model, c, [s])[0])
        first = t.predict_detail(mesh, "elbowBentLf", "mean", kind=kind)
        again = t.predict_detail(mesh, "elbowBentLf", "mean", kind=kind)
        assert first.predictor == ("pose_fields" if kind == "neutral_to_pose" else "network")
        v = torch.from_numpy(mesh.vertices)[None]
        d, r = normalised_delta(torch.from_numpy(bank.mean_delta(kind, "elbowBentLf"))[None])
        k = torch.tensor([PAIR_KINDS.index(kind)])
        with torch.no_grad():
            disp = fields.displacement(v, d, r, k)
            if kind == "neutral_to_pose":
                direct = (v + disp)[0].numpy()
            else:
                direct = vd(v, torch.from_numpy(mesh.normals)[None], torch.from_numpy(mesh.mu)[None], d, r, k,
                            torch.from_numpy(mesh.knn)[None], fields.weights(d, k), disp)["vertices"][0].numpy()
        assert np.array_equal(first.raw, again.raw)
        assert np.allclose(first.raw, direct, atol=1e-6)
        assert not np.allclose(first.raw, mesh.vertices, atol=1e-4)  # it does move the mesh


def test_transfer_derives_only_what_the_pair_kinds_predictor_reads(setup, tiny_corpus):
    """neutral_to_pose with the mean delta is the pose fields alone: it computes no latent, normals
    or neighbourhoods and ignores them (noise in their place changes nothing); the network kinds
    read all three, and their output follows the mesh's latent."""
    p, model, bank, _ = setup
    c = tiny_corpus
    t = Transfer(model, bank, p.corpus.sdf.k)
    i = c.split_indices("test")[0]
    s, lazy = held_out_neutral(t, c)
    out = t.predict(lazy, "kneeBentLf", "mean")
    assert lazy.derived() == set()
    rng = np.random.default_rng(0)
    noisy = t.prepare(c.vertices(s), c.faces, sdf_faces=c.body_faces, mu=rng.normal(size=p.model.latent))
    noisy.__dict__["normals"] = np.zeros_like(noisy.vertices)
    noisy.__dict__["knn"] = np.zeros((len(noisy.vertices), p.model.decoder.knn), np.int64)
    assert np.array_equal(t.predict(noisy, "kneeBentLf", "mean"), out)
    t.predict(lazy, "kneeBentLf", "nearest")  # the nearest identity is found from the latent
    assert lazy.derived() == {"mu"}
    posed = c.state(i, "elbowBentLf", "skinning")
    m1 = t.prepare(c.vertices(posed), c.faces, sdf_faces=c.body_faces)
    kind = "skinning_to_skinning_plus_blendshape"
    a = t.predict_detail(m1, "elbowBentLf", "mean", kind=kind)
    assert m1.derived() == {"mu", "normals", "knn"} and a.predictor == "network"
    m2 = t.prepare(c.vertices(posed), c.faces, sdf_faces=c.body_faces, mu=m1.mu + rng.normal(size=p.model.latent))
    assert not np.allclose(t.predict_detail(m2, "elbowBentLf", "mean", kind=kind).raw, a.raw)


def test_noise_gate(setup, tiny_corpus):
    """The bank measures its noise floor; a delta under 1.5 floors gives exactly the source, one
    over 3 floors the decoder's output untouched; magnitude 0 is the source exactly; the
    prediction is always source + gate * (decoder - source)."""
    import dataclasses

    from latent_model.transfer import GATE_HI, GATE_LO

    p, model, bank, path = setup
    c = tiny_corpus
    assert bank.noise_floor > 0 and LatentBank.load(path).noise_floor == pytest.approx(bank.noise_floor)
    t = Transfer(model, bank, c.config.sdf.k)
    z = np.zeros_like(bank.scale)
    unit = bank.scale / np.linalg.norm(np.ones_like(bank.scale))  # standardised norm 1
    assert t.noise_gate(z)[0] == 0.0
    assert t.noise_gate(unit * bank.noise_floor * GATE_LO * 0.99)[0] == 0.0
    assert t.noise_gate(unit * bank.noise_floor * GATE_HI * 1.01)[0] == 1.0
    g, signal = t.noise_gate(unit * bank.noise_floor * (GATE_LO + GATE_HI) / 2)
    assert g == pytest.approx(0.5) and signal == pytest.approx((GATE_LO + GATE_HI) / 2)
    # a mean of N deltas has 1/sqrt(N) of one delta's noise: the same length passes the gate
    weak = unit * bank.noise_floor * GATE_LO * 0.5
    assert t.noise_gate(weak)[0] == 0.0 and t.noise_gate(weak, averaged=16)[0] == 1.0
    assert t.noise_gate(weak, averaged=16)[1] == pytest.approx(4 * t.noise_gate(weak)[1])
    s0, mesh0 = held_out_neutral(t, c)
    n_train = len(bank.delta("neutral_to_pose", "kneeBentLf")[0])
    assert t.averaged("kneeBentLf", "mean_pose_delta", "neutral_to_pose") == n_train > 1
    assert t.averaged("kneeBentLf", "nearest_identity_delta", "neutral_to_pose") == 1
    out = t.predict_detail(mesh0, "kneeBentLf", "mean_pose_delta")
    assert out.signal == pytest.approx(t.noise_gate(bank.mean_delta("neutral_to_pose", "kneeBentLf"), n_train)[1])
    s, mesh = held_out_neutral(t, c)
    for kind in ("neutral_to_pose", "skinning_to_skinning_plus_blendshape"):
        for magnitude in (0.0, 1.0):
            o = t.predict_detail(mesh, "kneeBentLf", "nearest", magnitude=magnitude, kind=kind)
            assert np.allclose(o.vertices, mesh.vertices + o.gate * (o.raw - mesh.vertices), atol=1e-6)
            if magnitude == 0:
                assert o.gate == 0.0 and np.array_equal(o.vertices, mesh.vertices)
                if kind != "neutral_to_pose":  # the fields are linear in r; the network alone would have moved it
                    assert not np.allclose(o.raw, mesh.vertices)
    with pytest.raises(ValueError, match=r"magnitude must lie in \[0, 2\]"):
        t.predict(mesh, "kneeBentLf", magnitude=2.5)
    # a bank without a measured floor (older files) has no gate
    ungated = Transfer(model, dataclasses.replace(bank, noise_floor=0.0), c.config.sdf.k)
    o = ungated.predict_detail(mesh, "kneeBentLf", "nearest")
    assert o.gate == 1.0 and np.array_equal(o.vertices, o.raw)
