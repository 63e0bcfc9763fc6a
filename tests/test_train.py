"""Two-phase training on the tiny preset: frozen encoder, resume, logs, DDP."""
import json
import os
import subprocess
import sys

import pytest
import torch

from latent_model.config import preset
from latent_model.nn.model import LatentReRig
from latent_model.train.checkpoint import load_checkpoint
from latent_model.train.loop import select_device
from latent_model.train.phases import train_phase_a, train_phase_b


@pytest.fixture(scope="module")
def run_a(tiny_corpus, tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    p = preset("tiny")
    torch.manual_seed(0)
    model = LatentReRig(p.model)
    train_phase_a(model, p, tiny_corpus, run, torch.device("cpu"), steps=10, progress=False)
    return run, p, model


def test_phase_a_resumes_from_its_checkpoint(run_a, tiny_corpus):
    run, p, model = run_a
    state = torch.load(run / "phase_a.resume.pt", weights_only=True)
    assert state["step"] == 10
    train_phase_a(model, p, tiny_corpus, run, torch.device("cpu"), steps=20, progress=False)
    steps = [json.loads(x)["step"] for x in (run / "metrics_a.jsonl").read_text().splitlines()]
    assert steps == [5, 10, 15, 20]  # continued, not restarted
    assert torch.load(run / "phase_a.resume.pt", weights_only=True)["step"] == 20
    assert (run / "loss_a.png").stat().st_size > 1000


def test_phase_b_leaves_the_encoder_bit_identical(run_a, tiny_corpus):
    run, p, _ = run_a
    model, _, _ = load_checkpoint(run / "phase_a.safetensors")
    before = {k: v.clone() for k, v in model.state_dict().items() if not k.startswith("vertex_decoder.")}
    vd_before = {k: v.clone() for k, v in model.vertex_decoder.state_dict().items()}
    train_phase_b(model, p, tiny_corpus, run, torch.device("cpu"), steps=6, progress=False)
    assert not model.encoder.training and all(not q.requires_grad for q in model.encoder.parameters())
    after = model.state_dict()
    for k, v in before.items():
        assert torch.equal(v, after[k]), f"{k} changed in Phase B"
    assert any(not torch.equal(v, model.vertex_decoder.state_dict()[k]) for k, v in vd_before.items())
    # the pose prototypes were set from the training pairs: one unit row per pose with pairs
    norms = model.vertex_decoder.prototypes.norm(dim=-1)
    assert (norms > 0).sum() >= 2 and torch.allclose(norms[norms > 0], torch.ones(int((norms > 0).sum())))
    lines = (run / "metrics_b.jsonl").read_text().splitlines()
    assert {"pos", "knn", "knn_delta", "static", "smooth", "nrm"} <= set(json.loads(lines[-1]))


def test_device_auto_selection(monkeypatch):
    monkeypatch.delenv("LRR_DEVICE", raising=False)
    assert select_device().type == ("cuda" if torch.cuda.is_available() else "cpu")


def test_ddp_two_cpu_processes(tiny_corpus, tmp_path):
    run = tmp_path / "ddp"
    env = dict(os.environ, OMP_NUM_THREADS="1", LRR_DEVICE="cpu")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "latent_model.cli", "train", "all", "--preset", "tiny", "--corpus", str(tiny_corpus.path),
           "--run-dir", str(run), "--quiet"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]
    assert "2 process(es)" in r.stdout
    model, stored, _ = load_checkpoint(run / "model.safetensors", expect=preset("tiny"))
    assert stored.name == "tiny"
    assert (run / "loss_a.png").exists() and (run / "loss_b.png").exists()


def test_closed_form_fields_reproduce_the_training_pairs(run_a, tiny_corpus):
    """The ridge-fitted prototype fields, given the pose's mean training delta (the `mean`
    strategy), move training meshes much closer to their targets than no motion; with the fields
    left at zero they do not move them."""
    from latent_model.corpus.pairs import PAIR_KINDS
    from latent_model.train.closed_form import fit_prototype_fields, pose_prototypes
    from latent_model.train.data import PhaseBSampler
    from latent_model.train.phases import encode_rows

    run, p, _ = run_a
    model, _, _ = load_checkpoint(run / "phase_a.safetensors")
    c = tiny_corpus
    sampler = PhaseBSampler(c, p, 0)
    pairs = [q for q in sampler.by_kind["neutral_to_pose"] if q.pose in ("elbowBentLf", "kneeBentLf")]
    rows = sorted({c.row(s) for q in sampler.by_kind["neutral_to_pose"] for s in sampler.states(q)})
    mu = encode_rows(model, c, rows, torch.device("cpu"), progress=False)
    vd = model.vertex_decoder
    vd.set_pose_prototypes(pose_prototypes(sampler, c, mu, p.model.n_poses))

    def ratio() -> float:
        errs = []
        for q in pairs:
            s, t = sampler.states(q)
            v0, vt = torch.from_numpy(c.vertices(s))[None].float(), torch.from_numpy(c.vertices(t))[None].float()
            k, pose = PAIR_KINDS.index(q.kind), c.pose_index(q.pose)
            d, r = vd.prototypes[k, pose][None], vd.proto_r[k, pose][None]
            with torch.no_grad():
                pred = v0 + vd.prototype_displacement(vd.field_features(v0), d, r, torch.tensor([k]))
            errs.append(float((pred - vt).norm(dim=-1).mean() / (v0 - vt).norm(dim=-1).mean()))
        return sum(errs) / len(errs)

    assert ratio() == pytest.approx(1.0)
    info = fit_prototype_fields(vd, sampler, c, mu, seed=0, progress=False)
    assert info["pairs"] > 0 and vd.proto_fields.abs().sum() > 0
    assert ratio() < 0.6


def test_unscaled_field_fit_ignores_each_pairs_latent_amount(run_a, tiny_corpus):
    """vd_fit_scaled=False: every pair counts at amount 1, so doubling one training pair's latent
    delta leaves the fitted fields unchanged; the scaled fit (the default) weighs that pair by its
    amount and changes."""
    import dataclasses

    from latent_model.train.closed_form import fit_prototype_fields, pose_prototypes
    from latent_model.train.data import PhaseBSampler
    from latent_model.train.phases import encode_rows

    run, p, _ = run_a
    model, _, _ = load_checkpoint(run / "phase_a.safetensors")
    c = tiny_corpus
    sampler = PhaseBSampler(c, p, 0)
    rows = sorted({c.row(s) for q in sampler.by_kind["neutral_to_pose"] for s in sampler.states(q)})
    mu = encode_rows(model, c, rows, torch.device("cpu"), progress=False)
    vd = model.vertex_decoder
    vd.set_pose_prototypes(pose_prototypes(sampler, c, mu, p.model.n_poses))
    s, t = sampler.states(sampler.by_kind["neutral_to_pose"][0])
    doubled = mu.clone()
    doubled[c.row(t)] = mu[c.row(s)] + 2 * (mu[c.row(t)] - mu[c.row(s)])

    def fields(scaled: bool, rows_mu: torch.Tensor) -> torch.Tensor:
        vd.cfg = dataclasses.replace(vd.cfg, vd_fit_scaled=scaled)
        fit_prototype_fields(vd, sampler, c, rows_mu, seed=0, progress=False)
        return vd.proto_fields.clone()

    assert torch.equal(fields(False, mu), fields(False, doubled))
    assert not torch.allclose(fields(True, mu), fields(True, doubled))
