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
