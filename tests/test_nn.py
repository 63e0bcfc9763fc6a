"""Networks: shapes, any topology, SDF overfitting, checkpoints."""
import numpy as np
import pytest
import torch

from latent_model.config import preset
from latent_model.nn.model import LatentReRig
from latent_model.nn.vertex_decoder import knn_graph
from latent_model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint


@pytest.fixture(scope="module")
def tiny():
    torch.manual_seed(0)
    p = preset("tiny")
    return p, LatentReRig(p.model)


def test_encoder_shapes_and_count_invariance(tiny):
    p, m = tiny
    pts, vals = torch.randn(3, 500, 3) * 0.3, torch.randn(3, 500) * 0.05
    mu, logvar = m.encoder(pts, vals)
    assert mu.shape == (3, p.model.latent) and logvar.shape == (3, p.model.latent)
    # attention pooling is a weighted mean: duplicating every sample leaves mu unchanged
    mu2, _ = m.encoder(torch.cat([pts, pts], 1), torch.cat([vals, vals], 1))
    assert torch.allclose(mu, mu2, atol=1e-5)
    # and it is permutation invariant
    perm = torch.randperm(500)
    assert torch.allclose(mu, m.encoder(pts[:, perm], vals[:, perm])[0], atol=1e-5)


def test_default_latent_is_512():
    assert preset("standard").model.latent == 512 and preset("paper").model.latent == 512


@pytest.mark.parametrize("n_vertices", [700, 2345])
def test_vertex_decoder_any_topology(tiny, n_vertices):
    p, m = tiny
    v = torch.randn(2, n_vertices, 3) * 0.3
    n = torch.nn.functional.normalize(torch.randn(2, n_vertices, 3), dim=-1)
    knn = torch.from_numpy(np.stack([knn_graph(x.numpy(), p.model.decoder.knn) for x in v]))
    Z, P = p.model.latent, p.model.n_poses
    out = m.vertex_decoder(v, n, torch.randn(2, Z), torch.randn(2, Z), torch.tensor([0.5, 1.0]),
                           torch.tensor([0, 1]), knn, torch.softmax(torch.randn(2, P), -1), torch.zeros(2, n_vertices, 3))
    assert out["vertices"].shape == (2, n_vertices, 3)
    assert out["mask"].shape == (2, n_vertices, 1)
    assert torch.isfinite(out["vertices"]).all()
    # no parameter is sized by the vertex count
    assert all(n_vertices not in prm.shape for prm in m.vertex_decoder.parameters())


def test_sdf_decoder_overfits_a_few_shapes(tiny_corpus):
    from latent_model.nn import losses

    torch.manual_seed(0)
    p = preset("tiny")
    m = LatentReRig(p.model)
    c = tiny_corpus
    states = [c.state(0, None, "neutral"), c.state(1, "elbowBentLf", "skinning_plus_blendshape"),
              c.state(2, "cornerUpLf", "skinning_plus_blendshape")]
    pts = torch.from_numpy(np.stack([c.sdf(s)[0] for s in states])).float()
    vals = torch.from_numpy(np.stack([c.sdf(s)[1] for s in states])).float()
    params = list(m.encoder.parameters()) + list(m.sdf_decoder.parameters())
    opt = torch.optim.Adam(params, lr=3e-3)

    def loss_now():
        mu, _ = m.encoder(pts, vals)
        return losses.sdf_reconstruction(m.sdf_decoder(mu, pts), vals, p.model.sdf_clamp)

    with torch.no_grad():
        first = loss_now().item()
    for _ in range(600):
        opt.zero_grad()
        loss = loss_now()
        loss.backward()
        opt.step()
    with torch.no_grad():
        last = loss_now().item()
    assert last < first / 4, f"SDF loss fell only from {first:.4f} to {last:.4f}"


def test_checkpoint_round_trip_is_exact(tiny, tmp_path):
    p, m = tiny
    path = tmp_path / "m.safetensors"
    save_checkpoint(path, m, p, "a", 7)
    m2, stored, meta = load_checkpoint(path)
    assert stored == p and meta["step"] == "7"
    sd1, sd2 = m.state_dict(), m2.state_dict()
    assert sd1.keys() == sd2.keys()
    assert all(torch.equal(sd1[k], sd2[k]) for k in sd1)


def test_corrupt_and_mismatched_checkpoints_fail_clearly(tiny, tmp_path):
    p, m = tiny
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"this is not a checkpoint")
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(bad)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.safetensors")
    good = tmp_path / "tiny.safetensors"
    save_checkpoint(good, m, p, "a", 1)
    with pytest.raises(CheckpointError, match="preset 'tiny'"):
        load_checkpoint(good, expect=preset("standard"))
    with pytest.raises(CheckpointError, match="does not fit"):
        load_checkpoint(good, model=LatentReRig(preset("standard").model))
    # a file cut short (e.g. a copy interrupted) is reported, not crashed on
    cut = tmp_path / "cut.safetensors"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(CheckpointError):
        load_checkpoint(cut)


def test_vertex_decoder_learns_several_pairs_at_once(tiny_corpus):
    """A batch of different poses (large limb motion and near-static face poses) must be learnt
    together. Guards the failure where a median-seeking loss kept the decoder at 'no motion'."""
    from latent_model.nn import losses
    from latent_model.train.data import PhaseBSampler
    from latent_model.train.phases import PhaseBNet

    torch.manual_seed(0)
    p = preset("tiny")
    m = LatentReRig(p.model)
    c = tiny_corpus
    sampler = PhaseBSampler(c, p, 0, identities=[0])
    pairs = [q for q in sampler.by_kind["neutral_to_pose"] if q.pose in c.poses][:4]
    assert len({q.pose for q in pairs}) == 4
    b = sampler.collate(pairs)
    mu_rows = torch.randn(c.manifest["n_geometries"], p.model.latent)  # stand-in latents, distinct per state
    net = PhaseBNet(m, p, c.faces, mu_rows)
    opt = torch.optim.Adam(m.vertex_decoder.parameters(), lr=3e-3)
    no_motion = losses.vertex_losses(b.v_src, b.v_src, b.v_tgt, b.knn, None, p.loss)["pos"].item()
    for _ in range(150):
        loss, terms = net(b)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        last = net(b)[1]["pos"].item()
    assert last < no_motion / 3, f"vertex RMSE {last * 1000:.2f} mm vs {no_motion * 1000:.2f} mm without motion"


def test_pos_rel_weighs_each_pair_by_its_own_motion():
    """pos_rel = mean over pairs of RMSE / (RMS true motion + 2 mm): 1 mm of leakage on a still pair
    costs 0.5, the same 1 mm error on a pair moving 98 mm costs 0.01; pos (batch RMSE) barely sees it."""
    from latent_model.nn import losses

    V = 50
    src = torch.zeros(2, V, 3)
    tgt = src.clone()
    tgt[1, :, 0] = 0.098  # pair 1 moves 98 mm, pair 0 is still
    pred = tgt.clone()
    pred[:, :, 1] += 0.001  # 1 mm off everywhere, on both pairs
    knn = torch.from_numpy(knn_graph(np.random.default_rng(0).normal(size=(V, 3)), 4))[None].repeat(2, 1, 1)
    t = losses.vertex_losses(pred, src, tgt, knn, None, preset("tiny").loss)
    assert t["pos_rel"].item() == pytest.approx((0.001 / 0.002 + 0.001 / 0.100) / 2, rel=1e-4)
    assert t["pos"].item() == pytest.approx(0.001, rel=1e-4)


def _v1_file(path, model, p) -> None:
    """Write `model` as a format-1 checkpoint (flat `vd_` config, pose fields under vertex_decoder.)."""
    import json
    import math

    from safetensors.torch import save_file

    from latent_model.legacy import _V1_FIELDS, _V1_TENSORS

    d = p.to_dict()
    m = {k: v for k, v in d["model"].items() if k not in ("decoder", "fields")}
    for old, (section, name) in _V1_FIELDS.items():
        m[old] = d["model"][section][name]
    m.update(vd_detail=True, vd_dir_gain=math.sqrt(m["latent"]), vd_whiten=False, vd_basis=0, vd_prototypes=True,
             vd_fit_scaled=False, n_pair_kinds=4)
    back = {v: k for k, v in _V1_TENSORS.items()}
    tensors = {back.get(k, k): v.contiguous() for k, v in model.state_dict().items()}
    save_file(tensors, str(path), metadata={"format_version": "1", "preset": json.dumps({**d, "model": m}),
                                            "phase": "b", "step": "1", "extra": "{}"})
    return m


def test_format_1_checkpoints_upgrade_on_load_and_unshipped_designs_are_refused(tiny, tmp_path):
    """The shipped checkpoint was format 1: it loads with the same preset and tensors; a format-1
    checkpoint of an experiment that did not ship says so instead of loading something else."""
    import json

    from safetensors.torch import load_file, save_file

    p, m = tiny
    with torch.no_grad():
        m.pose_fields.readouts.normal_()
    path = tmp_path / "v1.safetensors"
    flat = _v1_file(path, m, p)
    m2, stored, meta = load_checkpoint(path)
    assert stored == p and meta["format_version"] == "1"
    assert all(torch.equal(v, m2.state_dict()[k]) for k, v in m.state_dict().items())
    basis = tmp_path / "basis.safetensors"
    bad = {**p.to_dict(), "model": {**flat, "vd_basis": 5}}
    save_file(load_file(str(path)), str(basis), metadata={"format_version": "1", "preset": json.dumps(bad),
                                                           "phase": "b", "step": "1", "extra": "{}"})
    with pytest.raises(CheckpointError, match="did not ship.*vd_basis=5"):
        load_checkpoint(basis)


def test_presets_are_the_shipped_design_at_three_sizes():
    """Defaults are the shipped model; tiny and paper change sizes only (never the design; tiny trains decoder v2
    without drawn combinations, which would dominate the tests' time)."""
    from latent_model.config import LossWeights, ModelConfig, TrainConfig

    std, tiny, paper = preset("standard"), preset("tiny"), preset("paper")
    assert std.model == ModelConfig(n_identities=56, n_poses=81) and std.train == TrainConfig() and std.loss == LossWeights()
    for p in (tiny, paper):
        assert p.loss == std.loss
        design = ("rff_sigma", "rff_seed", "proto_temp", "coef_max", "fit_ridge", "fit_kinds", "only_kinds")
        assert all(getattr(p.model.fields, k) == getattr(std.model.fields, k) for k in design), p.name
    assert paper.model.latent == 512 and paper.model.sdf_layers == 8 and paper.corpus.sdf.k == 16384
    assert std.model.fields.only_kinds == ("neutral_to_pose",)


def test_the_shipped_checkpoint_is_the_standard_preset_on_corpus_v4():
    """The defaults describe the model that ships: its stored preset is `preset("standard")`, decoder v2
    included, and it was trained on generator 4's corpus (rests, a validation split)."""
    import json

    from latent_model.checkpoint import read_metadata, stored_preset
    from latent_model.corpus.config import GENERATOR_VERSION
    from latent_model.shipped import ShippedPaths

    path = ShippedPaths.at().checkpoint
    stored, std = stored_preset(path), preset("standard")
    assert stored.model == std.model and stored.train == std.train and stored.loss == std.loss
    assert stored.corpus == std.corpus and stored.model.motion.enabled
    assert json.loads(read_metadata(path)["extra"])["corpus_generator"] == GENERATOR_VERSION


def _fields_with_random_prototypes(seed: int, kinds: int, temp: float | None = None):
    """(tiny preset, its PoseFields, the generator after drawing, prototypes (K, P, Z)): random
    prototypes of norm 2 for the first `kinds` pair kinds, none for the rest."""
    import dataclasses

    p = preset("tiny")
    cfg = p.model if temp is None else dataclasses.replace(p.model, fields=dataclasses.replace(p.model.fields, proto_temp=temp))
    fields = LatentReRig(cfg).pose_fields
    Z, P, K = cfg.latent, cfg.n_poses, cfg.n_pair_kinds
    g = torch.Generator().manual_seed(seed)
    protos = torch.zeros(K, P, Z)
    protos[:kinds] = torch.nn.functional.normalize(torch.randn(kinds, P, Z, generator=g), dim=-1) * 2.0
    fields.set_prototypes(protos)
    return p, fields, g, protos


def test_pose_prototypes_name_the_pose_and_round_trip(tmp_path):
    """A delta near one pose's prototype gets (almost) all the prototype weight, a blend of two
    splits it, zero rows never get weight, a kind without prototypes gives zeros (also before
    they are set), and the amount of a field is 1 for the mean delta and linear in r. The buffers
    round-trip through a checkpoint."""
    p, fields, g, protos = _fields_with_random_prototypes(seed=1, kinds=1, temp=0.05)
    Z, P = p.model.latent, p.model.n_poses
    k0, k1 = torch.zeros(2, dtype=torch.long), torch.ones(2, dtype=torch.long)
    assert LatentReRig(p.model).pose_fields.weights(torch.randn(2, Z), k0).abs().sum() == 0  # not set yet
    protos[0, P - 1] = 0.0  # a pose without training pairs
    fields.set_prototypes(protos)
    unit = torch.nn.functional.normalize(protos[0], dim=-1)
    d = torch.nn.functional.normalize(torch.stack([protos[0, 0] + 0.1 * torch.randn(Z, generator=g), unit[1] + unit[2]]), dim=-1)
    w = fields.weights(d, k0)
    assert w.shape == (2, P) and torch.allclose(w.sum(-1), torch.ones(2))
    assert w[0, 0] > 0.95
    assert w[1, 1] > 0.3 and w[1, 2] > 0.3
    assert w[:, P - 1].abs().max() == 0
    assert fields.weights(d, k1).abs().sum() == 0  # kind 1 has no prototypes
    mean_dir, mean_r = unit[:1], protos[0, :1].norm(dim=-1)
    assert fields.coefficients(mean_dir, mean_r, k0[:1])[0, 0].item() == pytest.approx(1.0, abs=1e-4)
    assert fields.coefficients(mean_dir, 0.5 * mean_r, k0[:1])[0, 0].item() == pytest.approx(0.5, abs=1e-4)
    m = LatentReRig(p.model)
    m.pose_fields.set_prototypes(protos)
    path = tmp_path / "p.safetensors"
    save_checkpoint(path, m, p, "b", 1)
    m2, _, _ = load_checkpoint(path)
    assert torch.equal(m2.pose_fields.prototypes, m.pose_fields.prototypes)


def test_pose_fields_act_only_for_their_pose_and_kind_and_scale_with_r():
    """A (kind, pose) field adds nothing at start, moves the mesh only when the delta is that
    pose's and the pair that kind, and its motion is linear in r (the magnitude slider)."""
    p, fields, g, protos = _fields_with_random_prototypes(seed=2, kinds=1)
    v = torch.randn(1, 300, 3, generator=g) * 0.3
    unit = protos[0] / 2.0

    def run(pose: int, kind: int, r: float) -> torch.Tensor:
        return fields.displacement(v, unit[pose:pose + 1], torch.tensor([r]), torch.tensor([kind]))

    assert run(0, 0, 2.0).abs().max() == 0  # nothing fitted yet
    with torch.no_grad():
        fields.readouts[0, 0].normal_(generator=g)
    assert run(0, 0, 2.0).norm(dim=-1).mean() > 1e-3
    assert run(1, 0, 2.0).abs().max() < 1e-6  # another pose's delta
    assert run(0, 1, 2.0).abs().max() < 1e-6  # another pair kind
    assert torch.allclose(run(0, 0, 1.0), 0.5 * run(0, 0, 2.0), atol=1e-6)


def test_cached_field_displacements_equal_the_direct_read_out():
    """The per-mesh cache (field displacements per fitted pose, read out in vertex chunks) gives
    the direct read-out, for a batch mixing kinds (one without fitted fields), a blended delta and
    more vertices than one chunk; a kind's cache is filled only when used."""
    from latent_model.nn.pose_fields import FieldCache

    p, fields, g, protos = _fields_with_random_prototypes(seed=3, kinds=2)
    with torch.no_grad():
        fields.readouts[0, :5].normal_(generator=g)  # kind 0: five fitted poses; kind 1: none
        fields.readouts[0, 7].normal_(generator=g)
    V = 5000  # > one 4096-vertex chunk
    v = torch.randn(2, V, 3, generator=g) * 0.3
    d = torch.nn.functional.normalize(0.6 * protos[0, 1] + 0.4 * protos[0, 7], dim=-1)
    dirs = torch.stack([d, protos[1, 2] / 2.0])
    r, kind = torch.tensor([2.0, 1.5]), torch.tensor([0, 1])
    direct = fields.displacement(v, dirs, r, kind)
    both, only0 = FieldCache(v), FieldCache(v[:1])
    cached = fields.displacement(v, dirs, r, kind, cache=both)
    one = fields.displacement(v[:1], dirs[:1], r[:1], kind[:1], cache=only0)
    assert sorted(both.by_kind) == [0, 1] and sorted(only0.by_kind) == [0]
    assert both.by_kind[0][0].tolist() == [0, 1, 2, 3, 4, 7] and len(both.by_kind[1][0]) == 0
    assert direct[0].norm(dim=-1).mean() > 1e-2  # the fields do move the mesh
    assert torch.allclose(cached, direct, atol=1e-5) and torch.allclose(one, direct[:1], atol=1e-5)


def test_decoder_network_adds_its_own_motion_to_the_fields():
    """The network starts from the fields' displacement and reads the prototype weights: with its
    refinement outputs live, its prediction differs from source + fields and moves when either input does."""
    p, fields, g, protos = _fields_with_random_prototypes(seed=4, kinds=2)
    torch.manual_seed(0)
    vd = LatentReRig(p.model).vertex_decoder.eval()
    with torch.no_grad():
        for par in vd.stage_out:  # a network that moves the mesh on its own
            par.weight.normal_(generator=g)
    Z, V = p.model.latent, 200
    v = torch.randn(1, V, 3, generator=g) * 0.3
    n = torch.nn.functional.normalize(torch.randn(1, V, 3, generator=g), dim=-1)
    knn = torch.from_numpy(knn_graph(v[0].numpy(), p.model.decoder.knn))[None]
    d, r, k = protos[0, 1:2] / 2.0, torch.tensor([2.0]), torch.tensor([0])
    w = fields.weights(d, k)
    disp = torch.randn(1, V, 3, generator=g) * 0.01
    with torch.no_grad():
        out = vd(v, n, torch.zeros(1, Z), d, r, k, knn, w, disp)["vertices"]
        assert (out - (v + disp)).norm(dim=-1).mean() > 1e-3
        assert (vd(v, n, torch.zeros(1, Z), d, r, k, knn, w, 2 * disp)["vertices"] - out).abs().max() > 1e-4
        assert (vd(v, n, torch.zeros(1, Z), d, r, k, knn, torch.roll(w, 1, dims=1), disp)["vertices"] - out).abs().max() > 1e-6


def test_alignment_is_zero_for_parallel_same_pose_deltas_and_ignores_other_poses():
    """Same-pose deltas of any length that point the same way cost 0; a 90 degree pair costs 1;
    deltas of different poses never enter (that is InfoNCE's job)."""
    from latent_model.nn import losses

    d = torch.tensor([[1.0, 0, 0], [3.0, 0, 0], [0, 1.0, 0], [0, 0, 2.0]])
    assert losses.alignment(d, torch.tensor([0, 0, 1, 2])).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.alignment(d, torch.tensor([0, 1, 0, 2])).item() == pytest.approx(1.0, abs=1e-6)
    assert losses.alignment(d, torch.tensor([0, 1, 2, 3])).item() == 0.0  # no same-pose pair
    # the gradient turns a misaligned delta toward its pose's other deltas
    x = torch.tensor([[1.0, 0, 0], [0.6, 0.8, 0]], requires_grad=True)
    losses.alignment(x, torch.tensor([0, 0])).backward()
    assert x.grad[1, 0] < 0 and x.grad[1, 1] > 0  # descent raises its x share, lowers its y share


def test_consistency_costs_length_and_direction_of_same_pose_deltas_only():
    """Equal same-pose deltas cost 0; parallel ones of different lengths cost (their lengths' difference squared
    over the sum of squares), which alignment leaves free; scaling every delta leaves it unchanged (no collapse);
    deltas of different poses never enter; in Phase A's loss when its weight is set."""
    from latent_model.nn import losses

    d = torch.tensor([[1.0, 0, 0], [1.0, 0, 0], [0, 2.0, 0], [0, 0, 1.0]])
    assert losses.consistency(d, torch.tensor([0, 0, 1, 2])).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.consistency(d, torch.tensor([0, 1, 2, 3])).item() == 0.0  # no same-pose pair
    long = torch.tensor([[1.0, 0, 0], [3.0, 0, 0]])
    assert losses.consistency(long, torch.tensor([0, 0])).item() == pytest.approx(4.0 / 10.0, abs=1e-6)
    assert losses.alignment(long, torch.tensor([0, 0])).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.consistency(5 * long, torch.tensor([0, 0])).item() == pytest.approx(0.4, abs=1e-6)
    x = torch.tensor([[1.0, 0, 0], [3.0, 0, 0]], requires_grad=True)
    losses.consistency(x, torch.tensor([0, 0])).backward()
    assert x.grad[0, 0] < 0 < x.grad[1, 0]  # descent lengthens the short one and shortens the long one


def test_phase_a_loss_has_the_consistency_term_when_weighted(tiny_corpus):
    import dataclasses

    from latent_model.config import preset
    from latent_model.nn.model import LatentReRig
    from latent_model.train.data import PhaseASampler
    from latent_model.train.phases import PhaseANet

    p = preset("tiny")
    b = PhaseASampler(tiny_corpus, p, seed=0).sample()
    torch.manual_seed(0)
    model = LatentReRig(p.model)
    on = dataclasses.replace(p, loss=dataclasses.replace(p.loss, consist=1.0))
    off = dataclasses.replace(p, loss=dataclasses.replace(p.loss, consist=0.0))
    _, terms = PhaseANet(model, on)(b)
    assert 0.0 < float(terms["consist"]) <= 2.0
    assert "consist" not in PhaseANet(model, off)(b)[1]


def test_mirror_cosine_penalises_shared_directions_only():
    """A pose's and its mirror's deltas of one character cost their cosine when it is positive:
    parallel 1, orthogonal or opposite 0; the gradient turns them apart."""
    from latent_model.nn import losses

    a = torch.tensor([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    b = torch.tensor([[2.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0]])
    assert losses.mirror_cosine(a[:1], b[:1]).item() == pytest.approx(1.0, abs=1e-6)
    assert losses.mirror_cosine(a[1:], b[1:]).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.mirror_cosine(a[:0], b[:0]).item() == 0.0
    x = torch.tensor([[1.0, 0.2, 0]], requires_grad=True)
    losses.mirror_cosine(x, torch.tensor([[1.0, 0, 0]])).backward()
    assert x.grad[0, 1] < 0  # descent raises the component the mirror lacks


def test_phase_a_batches_bring_mirrors_as_hard_negatives_when_asked(tiny_corpus):
    """With a_mirrors (the default) every sided pose of a batch comes with its mirror, paired per identity, and
    the mirror term enters Phase A's loss; without, a side is often drawn alone."""
    import dataclasses

    from latent_model.config import preset
    from latent_model.corpus.poses import mirror_pose
    from latent_model.nn.model import LatentReRig
    from latent_model.train.data import PhaseASampler
    from latent_model.train.phases import PhaseANet

    assert mirror_pose("elbowBentLf") == "elbowBentRt" and mirror_pose("elbowBentRt") == "elbowBentLf"
    assert mirror_pose("jawOpen") is None and mirror_pose("elbowBentLf+kneeBentLf") is None
    p = preset("tiny")
    p = dataclasses.replace(p, train=dataclasses.replace(p.train, a_mirrors=True, a_poses=5),
                            loss=dataclasses.replace(p.loss, mirror=1.0))
    sampler = PhaseASampler(tiny_corpus, p, seed=0)
    batches = [sampler.sample() for _ in range(6)]
    assert any(len(b.mirror_rows) for b in batches)
    names = tiny_corpus.poses
    for b in batches:
        for i, j in b.mirror_rows.tolist():
            assert b.neutral_of[i] == b.neutral_of[j]  # the same identity
            assert mirror_pose(names[int(b.pose_label[i])]) == names[int(b.pose_label[j])]
            assert i in b.contrast_rows and j in b.contrast_rows
    b = next(b for b in batches if len(b.mirror_rows))
    _, terms = PhaseANet(LatentReRig(p.model), p)(b)
    assert 0.0 <= float(terms["mirror"]) <= 1.0
    elbows = {names.index("elbowBentLf"), names.index("elbowBentRt")}

    def sides(batch) -> set[int]:
        return elbows & set(batch.pose_label[batch.contrast_rows].tolist())

    assert all(len(sides(b)) != 1 for b in batches)
    off = dataclasses.replace(p, train=dataclasses.replace(p.train, a_mirrors=False))
    plain = PhaseASampler(tiny_corpus, off, seed=0)
    assert any(len(sides(plain.sample())) == 1 for _ in range(20))


def test_a_preset_stored_before_the_consistency_term_reads_as_trained_without_it():
    import dataclasses
    import json

    from latent_model.config import Preset, preset

    p = preset("standard")
    d = json.loads(json.dumps(dataclasses.replace(p, loss=dataclasses.replace(p.loss, consist=2.5)).to_dict()))
    assert Preset.from_dict(d).loss.consist == 2.5
    del d["loss"]["consist"]
    assert Preset.from_dict(d).loss.consist == 0.0
