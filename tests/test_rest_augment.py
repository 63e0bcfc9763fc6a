"""Drawn rest configurations for decoder v2's training (train/rest_augment.py)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from latent_model.corpus.rests import REST_CONFIGS, TEST_RESTS, VAL_RESTS, RestConfig, get_rest
from latent_model.train.rest_augment import ANGLES, held_out_distance, random_rests, rest_ranges
from latent_model.types import FINAL


def test_drawn_rests_repeat_with_the_seed_spread_over_the_training_ranges_and_leave_the_t_pose_out():
    ranges = rest_ranges()
    drawn = random_rests(np.random.default_rng(3), 60)
    assert drawn == random_rests(np.random.default_rng(3), 60)
    assert drawn != random_rests(np.random.default_rng(4), 60)
    for a in ANGLES:
        lo, hi = ranges[a]
        values = [getattr(r, a) for r in drawn]
        assert lo <= min(values) and max(values) <= hi, a
        assert max(values) - min(values) > 0.7 * (hi - lo), a  # they fill the range, not one corner
    # the ranges are the training rests': the held-out T-pose's level arms stay unseen
    assert ranges["arms"][1] < REST_CONFIGS["tpose"].arms
    assert all(r.split == "train" for r in drawn) and not {r.name for r in drawn} & {*VAL_RESTS, *TEST_RESTS}


def test_drawn_rests_in_wider_ranges_keep_their_margin_from_every_held_out_rest():
    """Ranges past the training rests' (a DCC T-pose's level, straight arms) are drawn, but never within the margin
    of a validation or test rest; without a margin some draws come close to one."""
    wide = {"arms": (-40.0, 55.0), "elbows": (-45.0, 0.0)}
    drawn = random_rests(np.random.default_rng(3), 200, ranges=wide, margin=10.0)
    assert drawn == random_rests(np.random.default_rng(3), 200, ranges=wide, margin=10.0)
    arms, elbows = [r.arms for r in drawn], [r.elbows for r in drawn]
    assert max(arms) > 50 and min(elbows) < -42  # past the training rests' 38 and -38
    assert -40 <= min(arms) and max(arms) <= 55 and -45 <= min(elbows) and max(elbows) <= 0
    held = [r for r in REST_CONFIGS.values() if r.split != "train"]
    for r in drawn:
        assert all(max(abs(getattr(r, a) - getattr(h, a)) for a in ANGLES) >= 10.0 for h in held), r
    close = random_rests(np.random.default_rng(3), 200, ranges=wide)
    assert min(held_out_distance(vars(r)) for r in close) < 10.0
    assert held_out_distance(vars(REST_CONFIGS["tpose"])) == 0.0


def test_motion_config_checks_its_drawn_rest_ranges():
    from latent_model.config import MotionDecoderConfig

    MotionDecoderConfig(extra_rest_arms=(-40.0, 55.0), extra_rest_margin=10.0)
    for bad in ((55.0, -40.0), (1.0,), (0.0, 1.0, 2.0)):
        with pytest.raises(ValueError, match="extra_rest_arms"):
            MotionDecoderConfig(extra_rest_arms=bad, extra_rest_margin=10.0)
    with pytest.raises(ValueError, match="extra_rest_margin"):  # wider ranges need a margin from the held-out rests
        MotionDecoderConfig(extra_rest_elbows=(-45.0, 0.0))


def test_a_drawn_rest_is_posed_as_the_corpus_poses_a_named_one(tiny_corpus):
    """The same angles as a corpus rest give that corpus character's neutral and posed geometry."""
    from latent_model.corpus.build import init_generator_worker
    from latent_model.train.rest_augment import _character

    c = tiny_corpus
    i = next(i for i in c.split_indices("train") if c.identities[i].rest != "bind")
    named = get_rest(c.identities[i].rest)
    drawn = RestConfig("drawn_same", **{a: getattr(named, a) for a in ANGLES})
    pose = next(p for p in c.poses if p.startswith("elbow"))
    init_generator_worker()
    neutral, normals, posed, points, values, _ = _character((
        dataclasses.asdict(c.identities[i]), dataclasses.asdict(drawn), (pose,), dataclasses.asdict(c.config.sdf),
        c.body_faces.astype(np.int64), [0, 0, 0]))
    np.testing.assert_allclose(neutral, c.vertices(c.state(i, None, "neutral")), atol=1e-5)
    np.testing.assert_allclose(posed[0], c.vertices(c.state(i, pose, FINAL)), atol=1e-5)
    assert points.shape == (2, c.config.sdf.k, 3) and values.shape == (2, c.config.sdf.k)
    # and another rest is another neutral: the arms move
    other = RestConfig("drawn_other", **{**{a: getattr(named, a) for a in ANGLES}, "arms": named.arms + 20})
    moved = _character((dataclasses.asdict(c.identities[i]), dataclasses.asdict(other), (pose,),
                        dataclasses.asdict(c.config.sdf), c.body_faces.astype(np.int64), [0, 0, 0]))[0]
    assert np.linalg.norm(moved - neutral, axis=1).max() > 0.05


def test_motion_training_adds_every_training_person_in_drawn_rests(tiny_corpus, tmp_path, monkeypatch):
    """`extra_rests` > 0: the decoder trains on each training person in that many more rests, with the
    encoder's latents of those states and their posed geometry as targets."""
    import latent_model.train.motion as motion
    from latent_model.config import preset
    from latent_model.nn.model import LatentReRig

    seen = {}
    original = motion.train_motion_decoder

    def spy(*args, **kwargs):
        seen.update(cache=args[2], table=args[3], extra=kwargs.get("extra"))
        return original(*args, **kwargs)

    monkeypatch.setattr(motion, "train_motion_decoder", spy)
    p = preset("tiny")
    m = dataclasses.replace(p.model.motion, enabled=True, hidden=16, cond=16, steps=20, batch=4, vertices=64,
                            extra_rests=2, extra_rest_arms=(50.0, 60.0), extra_rest_margin=10.0)
    p = dataclasses.replace(p, model=dataclasses.replace(p.model, motion=m))
    torch.manual_seed(0)
    model = LatentReRig(p.model).eval()
    motion.train_motion_phase(model, p, tiny_corpus, tmp_path / "run", torch.device("cpu"), progress=False)
    extra, table, cache = seen["extra"], seen["table"], seen["cache"]
    train = tiny_corpus.split_indices("train")
    persons = [i for i in train if tiny_corpus.identities[i].rest == "bind"]
    assert extra is not None and extra.person == [i for i in persons for _ in range(2)]
    assert extra.ids[0] == tiny_corpus.manifest["n_identities"] and len(extra.ids) == 2 * len(persons)
    pose = extra.poses[0]
    for k, i in enumerate(extra.ids):
        assert i in extra and np.array_equal(cache.get(i)[0], extra.neutral[k])
        np.testing.assert_allclose(table.delta[(i, pose)], extra.mu_posed[k, 0] - extra.mu_neutral[k])
        assert not np.allclose(extra.target(i, pose), extra.neutral[k])  # the pose moves it
    assert all(50.0 <= r.arms <= 60.0 for r in extra.rests)  # the config's arm range, past the training rests'
    # each drawn character stands differently from its person's bind character
    assert all(np.abs(extra.neutral[k] - tiny_corpus.vertices(tiny_corpus.state(i, None, "neutral"))).max() > 0.01
               for k, i in enumerate(extra.person))


@pytest.mark.parametrize("name, value", [("extra_rests", 2), ("extra_combos", 40), ("other_prob", 0.3),
                                         ("averaged_input", True), ("other_mix", 0.5), ("extra_rest_margin", 10.0)])
def test_a_preset_stored_before_a_decoder_training_option_reads_as_trained_without_it(name, value):
    """Drawn rests, drawn combinations, another character's delta, the averaged count: a checkpoint's preset from
    before the option existed was trained without it, whatever the option's default is now."""
    import json

    from latent_model.config import Preset, preset

    p = preset("standard")
    d = json.loads(json.dumps(dataclasses.replace(p, model=dataclasses.replace(
        p.model, motion=dataclasses.replace(p.model.motion, **{name: value}))).to_dict()))
    assert getattr(Preset.from_dict(d).model.motion, name) == value
    del d["model"]["motion"][name]
    assert getattr(Preset.from_dict(d).model.motion, name) == 0


def test_a_person_stood_in_a_named_rest_is_that_rests_character(tiny_corpus):
    """characters_in_rests (bench/rest_transfer.py --rest): a person stood in a corpus rest configuration has that
    corpus character's neutral and posed geometry, and the encoder's latents of its own samples."""
    from latent_model.config import preset
    from latent_model.nn.model import LatentReRig
    from latent_model.train.rest_augment import characters_in_rests

    c = tiny_corpus
    j = next(i for i in c.split_indices("train") if c.identities[i].rest != "bind")
    person = next(i for i in c.split_indices("train")
                  if c.identities[i].rest == "bind" and c.identities[i].person_id == c.identities[j].person_id)
    pose = next(p for p in c.poses if p.startswith("elbow"))
    torch.manual_seed(0)
    model = LatentReRig(preset("tiny").model).eval()
    stands = [(person, get_rest(c.identities[j].rest)), (person, REST_CONFIGS["tpose"])]
    out = characters_in_rests(model, c, stands, (pose,), [[1, 0], [1, 1]], torch.device("cpu"), workers=1,
                              log=lambda m: None)
    assert out.person == [person, person] and [r.name for r in out.rests] == [c.identities[j].rest, "tpose"]
    np.testing.assert_allclose(out.neutral[0], c.vertices(c.state(j, None, "neutral")), atol=1e-5)
    np.testing.assert_allclose(out.target(out.ids[0], pose), c.vertices(c.state(j, pose, FINAL)), atol=1e-5)
    assert np.abs(out.neutral[1] - out.neutral[0]).max() > 0.05  # the T-pose raises the arms
    assert out.mu_neutral.shape == (2, model.cfg.latent) and out.mu_posed.shape == (2, 1, model.cfg.latent)
    assert not np.allclose(out.mu_neutral[1], out.mu_neutral[0])
