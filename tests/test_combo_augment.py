"""Drawn combinations of single body poses for decoder v2's training (train/combo_augment.py)."""
from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
import torch

from latent_model.corpus.poses import COMBO_POSES, POSES, get_pose
from latent_model.train.combo_augment import combination, draw_combinations, held_out_combinations
from latent_model.types import FINAL

BODY_SINGLES = [p for p, c in POSES.items() if c.group == "body" and not c.is_combo]


def test_drawn_combinations_repeat_with_the_seed_and_leave_the_evaluated_combinations_unseen():
    drawn = draw_combinations(BODY_SINGLES, 60, np.random.default_rng(3))
    assert [p.name for p in drawn] == [p.name for p in draw_combinations(BODY_SINGLES, 60, np.random.default_rng(3))]
    assert [p.name for p in drawn] != [p.name for p in draw_combinations(BODY_SINGLES, 60, np.random.default_rng(4))]
    held = held_out_combinations()
    assert len(held) == 2 and all(len(h) == 3 for h in held)
    corpus = {frozenset(get_pose(p).components) for p in COMBO_POSES}
    names = set()
    for p in drawn:
        comps = set(p.components)
        assert 2 <= len(comps) <= 3 and comps <= set(BODY_SINGLES)
        assert all(len(comps & h) < 2 for h in held), p.name  # no two poses of an evaluated combination together
        assert frozenset(comps) not in corpus
        bones = [j.bone for j in p.joints]
        assert len(bones) == len(set(bones)) == sum(len(get_pose(c).joints) for c in comps)
        names.add(p.name)
    assert len(names) == 60 and Counter(len(p.components) for p in drawn)[3] > 10


def test_drawn_amplitudes_scale_each_poses_angles_within_the_range():
    drawn = draw_combinations(BODY_SINGLES, 80, np.random.default_rng(5), sizes=(1, 2, 3), odds=(0.4, 0.3, 0.3),
                              amplitude=(0.3, 1.3))
    assert len({p.name for p in drawn}) == 80 and any(len(p.components) == 1 for p in drawn)
    scales = []
    for p in drawn:
        rotations = [j for c in p.components for j in get_pose(c).joints]
        assert [j.bone for j in p.joints] == [j.bone for j in rotations]
        scales += [j.degrees / r.degrees for j, r in zip(p.joints, rotations)]
    assert 0.3 - 1e-9 <= min(scales) < 0.45 and 1.15 < max(scales) <= 1.3 + 1e-9
    with pytest.raises(ValueError, match="combo_odds"):
        draw_combinations(BODY_SINGLES, 5, np.random.default_rng(5), sizes=(1, 2, 3), odds=(0.5, 0.5))
    # (1, 1), the config's default, is the vocabulary's angles: the same draws as none
    assert ([p.name for p in draw_combinations(BODY_SINGLES, 20, np.random.default_rng(5), amplitude=(1.0, 1.0))]
            == [p.name for p in draw_combinations(BODY_SINGLES, 20, np.random.default_rng(5))])
    # without amplitudes a lone pose is no combination
    assert all(len(p.components) >= 2 for p in draw_combinations(BODY_SINGLES, 30, np.random.default_rng(5),
                                                                 sizes=(1, 2), odds=(0.5, 0.5)))


def test_a_drawn_combination_poses_as_the_corpus_poses_its_own_combination(tiny_corpus):
    """The generator's geometry of a drawn combination equals the corpus's for the same single poses."""
    from latent_model.corpus.build import init_generator_worker
    from latent_model.train.combo_augment import _posed

    c = tiny_corpus
    name = next(p for p in c.poses if get_pose(p).is_combo and get_pose(p).group == "body")
    i = next(i for i in c.split_indices("train") if c.identities[i].rest != "bind")
    init_generator_worker()
    posed, points, values = _posed((dataclasses.asdict(c.identities[i]), [combination(get_pose(name).components)],
                                    dataclasses.asdict(c.config.sdf), c.body_faces.astype(np.int64), [0, 0]))
    np.testing.assert_allclose(posed[0], c.vertices(c.state(i, name, FINAL)), atol=1e-5)
    assert points.shape == (1, c.config.sdf.k, 3) and values.shape == (1, c.config.sdf.k)


def test_motion_training_adds_drawn_combinations_of_every_training_character(tiny_corpus, tmp_path, monkeypatch):
    """`extra_combos` > 0: each training character is also trained on drawn combinations, each with the encoder's
    latent of its posed state, the rig's geometry as the target, and its mean over the characters posed in it."""
    import latent_model.train.motion as motion
    from latent_model.config import preset
    from latent_model.nn.model import LatentReRig

    seen = {}
    original = motion.train_motion_decoder

    def spy(*args, **kwargs):
        seen.update(table=args[3], extra_poses=kwargs.get("extra_poses"))
        return original(*args, **kwargs)

    monkeypatch.setattr(motion, "train_motion_decoder", spy)
    p = preset("tiny")
    m = dataclasses.replace(p.model.motion, enabled=True, hidden=16, cond=16, steps=20, batch=4, vertices=64,
                            extra_combos=2, combos_per_character=1)
    p = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=m))
    torch.manual_seed(0)
    model = LatentReRig(p.model).eval()
    motion.train_motion_phase(model, p, tiny_corpus, tmp_path / "run", torch.device("cpu"), progress=False)
    extra, table = seen["extra_poses"], seen["table"]
    train = tiny_corpus.split_indices("train")
    assert extra is not None and len(extra.poses) == 2
    assert Counter(i for i, _ in extra.pairs) == {i: 1 for i in train}
    assert max(Counter(p for _, p in extra.pairs).values()) - min(Counter(p for _, p in extra.pairs).values()) <= 1
    for (i, name) in extra.pairs:
        neutral = tiny_corpus.vertices(tiny_corpus.state(i, None, "neutral"))
        assert np.abs(extra.targets[(i, name)] - neutral).max() > 0.01  # the combination moves it
        np.testing.assert_allclose(table.delta[(i, name)], extra.mu[(i, name)] - table.mu_neutral[i])
    name = extra.pairs[0][1]
    np.testing.assert_allclose(table.mean[name], np.mean([table.delta[q] for q in extra.pairs if q[1] == name], axis=0),
                               rtol=1e-6)

