"""Shared fixtures: one tiny corpus per test session (built in ~10 s once anny's cache exists)."""
from __future__ import annotations

import pytest

from latent_model.corpus.config import corpus_preset


@pytest.fixture(scope="session")
def tiny_config():
    return corpus_preset("tiny")


@pytest.fixture(scope="session")
def tiny_corpus(tmp_path_factory, tiny_config):
    from latent_model.corpus.build import build
    from latent_model.corpus.store import Corpus

    out = tmp_path_factory.mktemp("corpus") / "tiny"
    build(tiny_config, out, workers=2)
    return Corpus(out)


@pytest.fixture(scope="session")
def generator():
    from latent_model.corpus.states import StateGenerator

    return StateGenerator()


@pytest.fixture(scope="session")
def people(generator):
    """Two sampled (bind-rest) identities."""
    from latent_model.corpus.identities import sample_identities

    specs = sample_identities(8, 2, 1, 0, generator.rig.local_change_labels)
    return specs[0], specs[1]


@pytest.fixture(scope="session")
def untrained_model_moves():
    """A function (model, bank, corpus) that gives an untrained model something to say: the vertex
    decoder's weights jittered, pose prototypes from the bank's mean deltas and random read-outs,
    so each pose's fields move the mesh differently (what training does with real data)."""
    import torch

    from latent_model.corpus.pairs import split_bank_key
    from latent_model.types import PAIR_KINDS

    def give(model, bank, corpus) -> None:
        g = torch.Generator().manual_seed(0)
        fields = model.pose_fields
        protos = torch.zeros_like(fields.prototypes)
        for (kind, key), (_, d) in bank.deltas.items():
            protos[PAIR_KINDS.index(kind), corpus.pose_index(split_bank_key(kind, key)[0])] = torch.from_numpy(d.mean(0))
        fields.set_prototypes(protos)
        with torch.no_grad():
            fields.readouts.copy_(torch.randn(fields.readouts.shape, generator=g) * 0.01)
            for prm in model.vertex_decoder.parameters():
                prm.add_(torch.randn(prm.shape, generator=g) * 0.05)

    return give


@pytest.fixture(scope="session")
def tiny_motion(tiny_corpus, tmp_path_factory):
    """A tiny model whose motion decoder (decoder v2) is trained through Phase B's motion part on the tiny
    corpus (untrained encoder), its bank (no noise gate) and the Transfer on it: (transfer, preset)."""
    import dataclasses

    import torch

    from latent_model.bank import build_bank
    from latent_model.config import preset
    from latent_model.nn.model import LatentReRig
    from latent_model.train.motion import train_motion_phase
    from latent_model.transfer import Transfer

    p = preset("tiny")
    motion = dataclasses.replace(p.model.motion, enabled=True, hidden=32, cond=32, steps=300, batch=4, vertices=256,
                                 lr=3e-3)
    p = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=motion))
    torch.manual_seed(0)
    model = LatentReRig(p.model).eval()
    train_motion_phase(model, p, tiny_corpus, tmp_path_factory.mktemp("motion_run"), torch.device("cpu"), progress=False)
    bank = dataclasses.replace(build_bank(model, tiny_corpus, progress=False), noise_floor=0.0)
    return Transfer(model, bank, tiny_corpus.config.sdf.k), p
