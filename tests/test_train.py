"""Two-phase training on the tiny preset: frozen encoder, resume, logs, DDP."""
import json
import os
import subprocess
import sys

import pytest
import torch

from latent_model.config import preset
from latent_model.nn.model import LatentReRig
from latent_model.checkpoint import load_checkpoint
from latent_model.runtime import select_device
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
    before = {k: v.clone() for k, v in model.state_dict().items()
              if not k.startswith(("vertex_decoder.", "pose_fields.", "motion_decoder."))}
    vd_before = {k: v.clone() for k, v in model.vertex_decoder.state_dict().items()}
    train_phase_b(model, p, tiny_corpus, run, torch.device("cpu"), steps=6, progress=False)
    assert not model.encoder.training and all(not q.requires_grad for q in model.encoder.parameters())
    after = model.state_dict()
    for k, v in before.items():
        assert torch.equal(v, after[k]), f"{k} changed in Phase B"
    assert any(not torch.equal(v, model.vertex_decoder.state_dict()[k]) for k, v in vd_before.items())
    # the pose prototypes were set from the training pairs: one unit row per pose with pairs
    norms = model.pose_fields.prototypes.norm(dim=-1)
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


def _fields_from_phase_a(run_a, tiny_corpus):
    """(corpus, sampler of the bind-rest training characters, frozen-encoder mu per row, the model's
    PoseFields with prototypes set). Bind only: fields fixed in body coordinates cannot follow a pose
    across rest configurations (on tiny with its rest characters the fit leaves 0.76 of the error)."""
    from latent_model.encoding import encode_rows
    from latent_model.train.data import PhaseBSampler
    from latent_model.train.fit_pose_fields import pose_prototypes

    run, p, _ = run_a
    model, _, _ = load_checkpoint(run / "phase_a.safetensors")
    c = tiny_corpus
    sampler = PhaseBSampler(c, p, 0, identities=c.split_indices("train", rest="bind"))
    rows = sorted({c.row(s) for q in sampler.by_kind["neutral_to_pose"] for s in sampler.states(q)})
    mu = encode_rows(model, c, rows, torch.device("cpu"), progress=False)
    fields = model.pose_fields
    fields.set_prototypes(pose_prototypes(sampler, c, mu, p.model.n_poses))
    return c, sampler, mu, fields


def test_fitted_pose_fields_reproduce_the_training_pairs(run_a, tiny_corpus):
    """The ridge-fitted pose fields, given the pose's mean training delta (the `mean` strategy),
    move training meshes much closer to their targets than no motion; with the fields left at
    zero they do not move them."""
    from latent_model.types import PAIR_KINDS
    from latent_model.train.fit_pose_fields import fit_pose_fields

    c, sampler, mu, fields = _fields_from_phase_a(run_a, tiny_corpus)
    pairs = [q for q in sampler.by_kind["neutral_to_pose"] if q.pose in ("elbowBentLf", "kneeBentLf")]

    def ratio() -> float:
        errs = []
        for q in pairs:
            s, t = sampler.states(q)
            v0, vt = torch.from_numpy(c.vertices(s))[None].float(), torch.from_numpy(c.vertices(t))[None].float()
            k, pose = PAIR_KINDS.index(q.kind), c.pose_index(q.pose)
            d, r = fields.prototypes[k, pose][None], fields.proto_r[k, pose][None]
            with torch.no_grad():
                pred = v0 + fields.displacement(v0, d, r, torch.tensor([k]))
            errs.append(float((pred - vt).norm(dim=-1).mean() / (v0 - vt).norm(dim=-1).mean()))
        return sum(errs) / len(errs)

    assert ratio() == pytest.approx(1.0)
    info = fit_pose_fields(fields, sampler, c, mu, seed=0, progress=False)
    assert info["pairs"] > 0 and fields.readouts.abs().sum() > 0
    assert ratio() < 0.7  # 0.66 on tiny v4 (three bind training persons, one stylised; 64 features)


def test_field_fit_counts_every_pair_once_whatever_its_latent_amount(run_a, tiny_corpus):
    """Every pair along the prototype counts at amount 1 (the field is the pose's mean displacement):
    doubling one training pair's latent delta leaves the fitted fields unchanged, while turning it
    against the prototype drops the pair and changes them."""
    from latent_model.train.fit_pose_fields import fit_pose_fields

    c, sampler, mu, fields = _fields_from_phase_a(run_a, tiny_corpus)
    s, t = sampler.states(sampler.by_kind["neutral_to_pose"][0])

    def fitted(rows_mu: torch.Tensor) -> tuple[torch.Tensor, int]:
        info = fit_pose_fields(fields, sampler, c, rows_mu, seed=0, progress=False)
        return fields.readouts.clone(), info["pairs"]

    doubled, flipped = mu.clone(), mu.clone()
    doubled[c.row(t)] = mu[c.row(s)] + 2 * (mu[c.row(t)] - mu[c.row(s)])
    flipped[c.row(t)] = mu[c.row(s)] - (mu[c.row(t)] - mu[c.row(s)])
    base, n = fitted(mu)
    assert torch.equal(base, fitted(doubled)[0])
    away, n_away = fitted(flipped)
    assert n_away == n - 1 and not torch.allclose(base, away)


def test_phase_b_with_the_motion_decoder_starts_from_a_phase_a_checkpoint(run_a, tiny_corpus, tmp_path):
    """A preset with decoder v2 loads the Phase A checkpoint (whose motion decoder, untrained or absent, is
    Phase B's), runs the network and the motion part, and keeps the encoder."""
    import dataclasses
    import shutil

    from latent_model.checkpoint import load_phase_a

    run, p, _ = run_a
    motion = dataclasses.replace(p.model.motion, enabled=True, hidden=16, cond=16, steps=5, batch=2, vertices=64)
    pm = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=motion))
    shutil.copy(run / "phase_a.safetensors", tmp_path / "phase_a.safetensors")
    model = LatentReRig(pm.model)
    load_phase_a(tmp_path / "phase_a.safetensors", model, expect=pm)
    enc = {k: v.clone() for k, v in model.encoder.state_dict().items()}
    train_phase_b(model, pm, tiny_corpus, tmp_path, torch.device("cpu"), steps=2, progress=False)
    assert float(model.motion_decoder.delta_scale) > 0 and model.motion_decoder.mu_basis.abs().sum() > 0
    assert all(torch.equal(v, model.encoder.state_dict()[k]) for k, v in enc.items())


def test_decoder_v2_retrains_alone_on_a_finished_phase_b(run_a, tiny_corpus, tmp_path):
    """`lrr train motion`: decoder v2 re-trains on a run's Phase B checkpoint and comes out as Phase B's own
    motion part would (same seeds), the network untouched; another motion config trains another decoder."""
    import dataclasses
    import shutil

    from latent_model.train.phases import train

    run, p, _ = run_a
    motion = dataclasses.replace(p.model.motion, enabled=True, hidden=16, cond=16, steps=8, batch=2, vertices=64)
    pm = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=motion))
    shutil.copy(run / "phase_a.safetensors", tmp_path / "phase_a.safetensors")
    full, _, _ = load_checkpoint(train(pm, tiny_corpus, tmp_path, "b", torch.device("cpu"), progress=False))
    network = {k: v.clone() for k, v in full.state_dict().items() if not k.startswith("motion_decoder.")}
    again, _, _ = load_checkpoint(train(pm, tiny_corpus, tmp_path, "motion", torch.device("cpu"), progress=False))
    for k, v in again.state_dict().items():
        ref = network.get(k, full.state_dict()[k])
        assert torch.allclose(v, ref, atol=1e-5), k
    other = dataclasses.replace(pm, model=dataclasses.replace(pm.model, motion=dataclasses.replace(motion, translation=5.0)))
    moved, _, _ = load_checkpoint(train(other, tiny_corpus, tmp_path, "motion", torch.device("cpu"), progress=False))
    assert not torch.allclose(moved.motion_decoder.out.weight, full.motion_decoder.out.weight)
    assert all(torch.equal(v, moved.state_dict()[k]) for k, v in network.items())


def test_train_set_overrides_a_preset_field_and_the_checkpoint_keeps_it(tiny_corpus, tmp_path):
    """`lrr train --set train.a_mirrors=false --set loss.mirror=0` trains with those values (not the defaults) and
    stores them in the checkpoint's preset (what bank and evaluate read); a wrong field or type is refused with the
    valid names, before any training."""
    from latent_model.config import override

    assert preset("tiny").train.a_mirrors is True and preset("tiny").loss.mirror == 1.0  # the defaults
    p = override(preset("tiny"), ["train.a_mirrors=false", "loss.mirror=0", "model.motion.steps=7"])
    assert p.train.a_mirrors is False and p.loss.mirror == 0.0 and p.model.motion.steps == 7
    assert p.model.latent == preset("tiny").model.latent
    for bad, said in (("loss.mirrors=1", "valid:"), ("train.a_mirrors=3", "bool"), ("corpus.seed=1", "SECTION"),
                      ("loss.mirror", "SECTION")):
        with pytest.raises(ValueError, match=said):
            override(preset("tiny"), [bad])
    env = dict(os.environ, LRR_DEVICE="cpu")
    base = [sys.executable, "-m", "latent_model.cli", "train", "phase-a", "--preset", "tiny",
            "--corpus", str(tiny_corpus.path), "--run-dir", str(tmp_path), "--quiet"]
    r = subprocess.run(base + ["--set", "loss.mirrors=1"], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "loss.mirrors" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(base + ["--set", "train.a_mirrors=false", "--set", "loss.mirror=0"], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    _, stored, _ = load_checkpoint(tmp_path / "phase_a.safetensors")
    assert stored.train.a_mirrors is False and stored.loss.mirror == 0.0
    assert '"mirror"' not in (tmp_path / "metrics_a.jsonl").read_text()  # the term was off
