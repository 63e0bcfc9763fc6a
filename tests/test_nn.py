"""Networks: shapes, any topology, SDF overfitting, checkpoints."""
import numpy as np
import pytest
import torch

from latent_model.config import preset
from latent_model.nn.model import LatentReRig
from latent_model.nn.vertex_decoder import knn_graph
from latent_model.train.checkpoint import CheckpointError, load_checkpoint, save_checkpoint


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
    knn = torch.from_numpy(np.stack([knn_graph(x.numpy(), p.model.vd_knn) for x in v]))
    Z = p.model.latent
    out = m.vertex_decoder(v, n, torch.randn(2, Z), torch.randn(2, Z), torch.tensor([0.5, 1.0]),
                           torch.tensor([0, 1]), knn)
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


def test_direction_gain_defaults_to_the_old_behaviour_for_old_checkpoints(tiny):
    """Checkpoints written before vd_dir_gain load with gain 1 (what they were trained with); presets use sqrt(Z)."""
    import dataclasses

    from latent_model.config import ModelConfig, Preset

    p = tiny[0]
    assert p.model.vd_dir_gain == pytest.approx(np.sqrt(p.model.latent))
    d = p.to_dict()
    del d["model"]["vd_dir_gain"]
    assert Preset.from_dict(d).model.vd_dir_gain == 1.0
    plain = dataclasses.replace(p.model, vd_whiten=False)  # the gain is what an unwhitened decoder reads
    m = LatentReRig(plain).vertex_decoder
    m1 = LatentReRig(dataclasses.replace(plain, vd_dir_gain=1.0)).vertex_decoder
    m1.load_state_dict(m.state_dict())
    mu, direction = torch.randn(1, p.model.latent), torch.randn(1, p.model.latent)
    r, kind = torch.ones(1), torch.zeros(1, dtype=torch.long)
    assert not torch.allclose(m.condition(mu, direction, r, kind), m1.condition(mu, direction, r, kind))
    assert ModelConfig().vd_dir_gain == 1.0


def test_direction_whitening_pulls_nearly_parallel_deltas_apart():
    """Two poses whose raw directions nearly coincide (cos 0.97, as kneeBentLf/Rt) among dominant
    ones: after the ZCA preconditioner they are far apart, and the training directions come out
    decorrelated at unit scale. Fails if the whitening is skipped or mis-scaled."""
    import dataclasses

    Z = 16
    cfg = dataclasses.replace(preset("tiny").model, latent=Z, vd_whiten=True)
    vd = LatentReRig(cfg).vertex_decoder
    g = torch.Generator().manual_seed(0)
    base = torch.randn(Z, generator=g)
    a = base + 0.25 * torch.randn(Z, generator=g)
    b = base + 0.25 * torch.randn(Z, generator=g)
    assert torch.nn.functional.cosine_similarity(a, b, dim=0) > 0.9
    samples = torch.cat([a + 0.02 * torch.randn(200, Z, generator=g), b + 0.02 * torch.randn(200, Z, generator=g),
                         torch.randn(400, Z, generator=g) * torch.linspace(3, 0.1, Z)])
    u = torch.nn.functional.normalize(samples, dim=-1)
    vd.set_direction_whitening(u, eps_rel=1e-3)
    w = vd.dir_whiten
    wa, wb = torch.nn.functional.normalize(a, dim=0) @ w, torch.nn.functional.normalize(b, dim=0) @ w
    assert torch.nn.functional.cosine_similarity(wa, wb, dim=0) < 0.5
    moment = (u @ w).T @ (u @ w) / len(u)
    eig = torch.linalg.eigvalsh(moment)
    assert eig.max() / eig.min() < 5.0  # raw: > 100
    assert moment.diagonal().mean().item() == pytest.approx(1.0, rel=1e-3)


def test_basis_branch_is_silent_at_start_and_saved(tmp_path):
    """The bilinear basis adds nothing before training (zero coefficients) and round-trips, as does
    the whitening buffer; configs without the fields (older checkpoints) get neither."""
    import dataclasses

    from latent_model.config import Preset

    p = preset("tiny")
    p2 = dataclasses.replace(p, model=dataclasses.replace(p.model, vd_basis=5, vd_whiten=True))
    torch.manual_seed(0)
    m = LatentReRig(p2.model)
    assert m.vertex_decoder.basis_coef.weight.abs().sum() == 0
    m.vertex_decoder.dir_whiten.mul_(2.0)
    path = tmp_path / "b.safetensors"
    save_checkpoint(path, m, p2, "b", 1)
    m2, stored, _ = load_checkpoint(path)
    assert stored.model.vd_basis == 5 and torch.equal(m2.vertex_decoder.dir_whiten, m.vertex_decoder.dir_whiten)
    d = p.to_dict()
    del d["model"]["vd_basis"], d["model"]["vd_whiten"]
    old = Preset.from_dict(d).model
    assert old.vd_basis == 0 and not old.vd_whiten
    assert not hasattr(LatentReRig(old).vertex_decoder, "basis")


def test_pose_prototypes_name_the_pose_and_round_trip(tmp_path):
    """A delta near one pose's prototype gets (almost) all the prototype weight, a blend of two
    splits it, zero rows never get weight, a kind without prototypes gives zeros (also before
    they are set), and the amount of a field is 1 for the mean delta and linear in r. The buffers
    round-trip; configs without the field (older checkpoints) have no prototype input."""
    import dataclasses

    from latent_model.config import Preset

    p = preset("tiny")
    cfg = dataclasses.replace(p.model, vd_proto_temp=0.05)
    assert p.model.vd_prototypes
    vd = LatentReRig(cfg).vertex_decoder
    Z, P, K = cfg.latent, cfg.n_poses, cfg.n_pair_kinds
    k0, k1 = torch.zeros(2, dtype=torch.long), torch.ones(2, dtype=torch.long)
    assert vd.prototype_weights(torch.randn(2, Z), k0).abs().sum() == 0  # not set yet
    g = torch.Generator().manual_seed(1)
    protos = torch.zeros(K, P, Z)
    protos[0] = torch.randn(P, Z, generator=g) * 3.0
    protos[0, P - 1] = 0.0  # a pose without training pairs
    vd.set_pose_prototypes(protos)
    unit = torch.nn.functional.normalize(protos[0], dim=-1)
    d = torch.nn.functional.normalize(torch.stack([protos[0, 0] + 0.1 * torch.randn(Z, generator=g), unit[1] + unit[2]]), dim=-1)
    w = vd.prototype_weights(d, k0)
    assert w.shape == (2, P) and torch.allclose(w.sum(-1), torch.ones(2))
    assert w[0, 0] > 0.95
    assert w[1, 1] > 0.3 and w[1, 2] > 0.3
    assert w[:, P - 1].abs().max() == 0
    assert vd.prototype_weights(d, k1).abs().sum() == 0  # kind 1 has no prototypes
    mean_dir, mean_r = unit[:1], protos[0, :1].norm(dim=-1)
    amount = vd.prototype_coefficients(mean_dir, mean_r, k0[:1])
    assert amount[0, 0].item() == pytest.approx(1.0, abs=1e-4)
    assert vd.prototype_coefficients(mean_dir, 0.5 * mean_r, k0[:1])[0, 0].item() == pytest.approx(0.5, abs=1e-4)
    c = vd.condition(torch.zeros(2, Z), d, torch.ones(2), k0)
    assert torch.isfinite(c).all()
    m = LatentReRig(p.model)
    m.vertex_decoder.set_pose_prototypes(protos)
    path = tmp_path / "p.safetensors"
    save_checkpoint(path, m, p, "b", 1)
    m2, stored, _ = load_checkpoint(path)
    assert stored.model.vd_prototypes and torch.equal(m2.vertex_decoder.prototypes, m.vertex_decoder.prototypes)
    dd = p.to_dict()
    for key in ("vd_prototypes", "vd_proto_temp", "vd_proto_fields"):
        del dd["model"][key]
    old = Preset.from_dict(dd).model
    assert not old.vd_prototypes and not hasattr(LatentReRig(old).vertex_decoder, "prototypes")


def _decoder_with_random_prototypes(seed: int, kinds: int):
    """(tiny preset, its vertex decoder in eval mode, the generator after drawing, prototypes
    (K, P, Z)): random prototypes of norm 2 for the first `kinds` pair kinds, none for the rest."""
    p = preset("tiny")
    torch.manual_seed(0)
    vd = LatentReRig(p.model).vertex_decoder.eval()
    Z, P, K = p.model.latent, p.model.n_poses, p.model.n_pair_kinds
    g = torch.Generator().manual_seed(seed)
    protos = torch.zeros(K, P, Z)
    protos[:kinds] = torch.nn.functional.normalize(torch.randn(kinds, P, Z, generator=g), dim=-1) * 2.0
    vd.set_pose_prototypes(protos)
    return p, vd, g, protos


def test_prototype_fields_act_only_for_their_pose_and_kind_and_scale_with_r():
    """A (kind, pose) field adds nothing at start, moves the mesh only when the delta is that
    pose's and the pair that kind, and its motion is linear in r (the magnitude slider)."""
    p, vd, g, protos = _decoder_with_random_prototypes(seed=2, kinds=1)
    Z = p.model.latent
    V = 300
    v = torch.randn(1, V, 3, generator=g) * 0.3
    n = torch.nn.functional.normalize(torch.randn(1, V, 3, generator=g), dim=-1)
    knn = torch.from_numpy(knn_graph(v[0].numpy(), p.model.vd_knn))[None]
    unit = protos[0] / 2.0

    def run(pose: int, kind: int, r: float) -> torch.Tensor:
        with torch.no_grad():
            return vd(v, n, torch.zeros(1, Z), unit[pose:pose + 1], torch.tensor([r]), torch.tensor([kind]), knn)["vertices"]

    before = run(0, 0, 2.0)
    with torch.no_grad():
        vd.proto_fields[0, 0].normal_(generator=g)
    moved = (run(0, 0, 2.0) - before).norm(dim=-1).mean()
    assert moved > 1e-3
    assert (run(1, 0, 2.0) - vd_unchanged(vd, run, 1, 0, 2.0)).abs().max() < 1e-5
    assert (run(0, 1, 2.0) - vd_unchanged(vd, run, 0, 1, 2.0)).abs().max() < 1e-5
    # linear in r: the field part at r=1 is half the one at r=2 (the rest of the decoder is
    # not linear in r, so compare the field's own contribution)
    field2 = run(0, 0, 2.0) - vd_unchanged(vd, run, 0, 0, 2.0)
    field1 = run(0, 0, 1.0) - vd_unchanged(vd, run, 0, 0, 1.0)
    assert torch.allclose(field1, 0.5 * field2, atol=1e-4)


def vd_unchanged(vd, run, pose: int, kind: int, r: float) -> torch.Tensor:
    """`run` with the prototype fields temporarily zeroed."""
    saved = vd.proto_fields.clone()
    vd.proto_fields.zero_()
    try:
        return run(pose, kind, r)
    finally:
        vd.proto_fields.copy_(saved)


def test_cached_field_displacements_equal_the_direct_read_out():
    """The mesh-feature cache (field displacements per fitted pose, read out in vertex chunks)
    gives the decoder's own output, for a batch mixing kinds (one without fitted fields), a
    blended delta and more vertices than one chunk; a kind's cache is filled only when used."""
    from latent_model.nn.vertex_decoder import MeshFeatures

    p, vd, g, protos = _decoder_with_random_prototypes(seed=3, kinds=2)
    Z = p.model.latent
    with torch.no_grad():
        vd.proto_fields[0, :5].normal_(generator=g)  # kind 0: five fitted poses; kind 1: none
        vd.proto_fields[0, 7].normal_(generator=g)
    V = 5000  # > one 4096-vertex chunk
    v = torch.randn(2, V, 3, generator=g) * 0.3
    n = torch.nn.functional.normalize(torch.randn(2, V, 3, generator=g), dim=-1)
    knn = torch.stack([torch.from_numpy(knn_graph(x.numpy(), p.model.vd_knn)) for x in v])
    d = torch.nn.functional.normalize(0.6 * protos[0, 1] + 0.4 * protos[0, 7], dim=-1)
    dirs = torch.stack([d, protos[1, 2] / 2.0])
    r, kind = torch.tensor([2.0, 1.5]), torch.tensor([0, 1])
    with torch.no_grad():
        direct = vd(v, n, torch.zeros(2, Z), dirs, r, kind, knn)["vertices"]
        feats = vd.mesh_features(v, n)
        assert isinstance(feats, MeshFeatures) and feats.fields == {}
        cached = vd(v, n, torch.zeros(2, Z), dirs, r, kind, knn, features=feats)["vertices"]
        only0 = vd.mesh_features(v[:1], n[:1])
        vd(v[:1], n[:1], torch.zeros(1, Z), dirs[:1], r[:1], kind[:1], knn[:1], features=only0)
    assert sorted(feats.fields) == [0, 1] and sorted(only0.fields) == [0]
    assert feats.fields[0][0].tolist() == [0, 1, 2, 3, 4, 7] and len(feats.fields[1][0]) == 0
    assert (direct[0] - v[0]).norm(dim=-1).mean() > 1e-2  # the fields do move the mesh
    assert torch.allclose(cached, direct, atol=1e-5)
    with torch.no_grad():  # one kind per batch (the fast path) as well
        one = vd(v[:1], n[:1], torch.zeros(1, Z), dirs[:1], r[:1], kind[:1], knn[:1], features=only0)["vertices"]
    assert torch.allclose(one, direct[:1], atol=1e-5)


def test_fields_only_kinds_use_the_fields_alone_at_inference_only():
    """A kind in vd_fields_only_kinds predicts source + prototype fields in eval mode (also in a
    batch mixing kinds, and through the mesh-feature cache); other kinds and training are unchanged."""
    import dataclasses

    from latent_model.corpus.pairs import PAIR_KINDS

    p = preset("tiny")
    cfg = dataclasses.replace(p.model, vd_fields_only_kinds=(PAIR_KINDS[0],))
    torch.manual_seed(0)
    vd = LatentReRig(cfg).vertex_decoder
    torch.manual_seed(0)
    plain = LatentReRig(p.model).vertex_decoder
    Z, P, K = cfg.latent, cfg.n_poses, cfg.n_pair_kinds
    g = torch.Generator().manual_seed(4)
    protos = torch.nn.functional.normalize(torch.randn(K, P, Z, generator=g), dim=-1) * 2.0
    with torch.no_grad():
        for m in (vd, plain):
            m.set_pose_prototypes(protos)
            m.proto_fields[:2, :3].copy_(torch.randn(2, 3, cfg.vd_proto_fields + 1, 3, generator=g))
            for par in m.stage_out:  # a network that moves the mesh on its own
                par.weight.normal_(generator=g)
    plain.load_state_dict(vd.state_dict())
    V = 200
    v = torch.randn(2, V, 3, generator=g) * 0.3
    n = torch.nn.functional.normalize(torch.randn(2, V, 3, generator=g), dim=-1)
    knn = torch.stack([torch.from_numpy(knn_graph(x.numpy(), cfg.vd_knn)) for x in v])
    dirs, r, kind = protos[[0, 1], [1, 2]] / 2.0, torch.tensor([2.0, 2.0]), torch.tensor([0, 1])
    fields = vd.prototype_displacement(vd.field_features(v), dirs, r, kind).detach()

    def run(m, train: bool, features=None):
        m.train(train)
        with torch.no_grad():
            return m(v, n, torch.zeros(2, Z), dirs, r, kind, knn, features=features)["vertices"]

    out = run(vd, False)
    assert torch.allclose(out[0], v[0] + fields[0], atol=1e-5)  # kind 0: the fields alone
    assert torch.allclose(out[1], run(plain, False)[1], atol=1e-6)  # kind 1: the whole decoder
    assert (run(plain, False)[0] - out[0]).norm(dim=-1).mean() > 1e-3  # which differs from the fields alone
    assert torch.allclose(run(vd, True), run(plain, True), atol=1e-6)  # training: unchanged
    one = vd.eval()(v[:1], n[:1], torch.zeros(1, Z), dirs[:1], r[:1], kind[:1], knn[:1],
                    features=vd.mesh_features(v[:1], n[:1]))["vertices"]
    assert torch.allclose(one, out[:1], atol=1e-5)  # the early return, through the cache


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
