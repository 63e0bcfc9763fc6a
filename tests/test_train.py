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
