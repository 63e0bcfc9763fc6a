"""Corpus v4's characters (a person in one rest configuration): splits, rests, stylised persons."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from latent_model.corpus.config import corpus_preset


@pytest.fixture(scope="module")
def standard_specs():
    from latent_model.corpus.build import plan

    return plan(corpus_preset("standard"))[0]


def _persons(specs, split: str) -> set[str]:
    return {s.person_id for s in specs if s.split == split}


def test_validation_and_test_never_meet_training(standard_specs):
    """Splits are of persons (every character of a person shares its split), and the rests the
    validation and test persons stand in are never a training character's (but for bind)."""
    from latent_model.corpus.rests import get_rest

    specs = standard_specs
    train, val, test = (_persons(specs, s) for s in ("train", "val", "test"))
    assert len(train) == 56 and len(val) == 8 and len(test) == 14
    assert not train & val and not train & test and not val & test
    for s in specs:
        assert {t.split for t in specs if t.person_id == s.person_id} == {s.split}, s.id
        assert s.rest == "bind" or get_rest(s.rest).split == s.split, f"{s.id} stands in another split's rest"
    train_rests = {s.rest for s in specs if s.split == "train"}
    held_out = {s.rest for s in specs if s.split in ("val", "test")} - {"bind"}
    assert len(train_rests) >= 5 and not train_rests & held_out
    assert not {s.rest for s in specs if s.split == "val"} & {s.rest for s in specs if s.split == "test"} - {"bind"}
    by_person = Counter(s.person_id for s in specs if s.split == "test")
    assert all(n >= 4 for n in by_person.values())  # bind + at least three held-out rests
    assert all(s.person_id == s.id and s.rest == "bind" for s in specs[:78])  # bind characters keep their index


def test_stylised_training_persons_are_their_own_recipes(standard_specs):
    """At least 10% of the training persons are stylised, each by a seeded recipe of its own that
    stays away from the two stylised test characters; the same config gives the same persons."""
    from latent_model.corpus.build import plan
    from latent_model.corpus.identities import _STYLISED, MIN_RECIPE_DISTANCE, recipe_distance

    specs = standard_specs
    train = [s for s in specs if s.split == "train" and s.rest == "bind"]
    styled = [s for s in train if s.stylised]
    assert len(styled) >= 0.10 * len(train)
    assert sum(s.stylised for s in specs if s.split == "val" and s.rest == "bind") == 1
    labels = {k for recipe in _STYLISED for k in recipe} | {"torso-scale-horiz-incr", "measure-neck-height-incr"}
    for s in styled:
        mine = {k: v for k, v in s.local_changes.items() if k in labels and abs(v) >= 0.6}
        assert mine, f"{s.id} has no stylised proportion"
        assert min(recipe_distance(s.local_changes, t) for t in _STYLISED) >= MIN_RECIPE_DISTANCE
    assert len({repr(sorted(s.local_changes.items())) for s in styled}) == len(styled)
    assert [s.to_dict() for s in plan(corpus_preset("standard"))[0]] == [s.to_dict() for s in specs]


def test_a_rest_keeps_the_variants_rules(generator, people):
    """In a rest configuration the standing character is the neutral; a face-only pose's skinning
    state is that neutral and its final state its blendshape state, exactly, as in the bind rest;
    a body pose's blendshape state keeps the bones where the rest has them."""
    a, _ = people
    neutral = generator.neutral(a, "tpose")
    g = generator.pose(a, "browDwLf", "tpose")
    assert np.array_equal(g.skinning, neutral) and np.array_equal(g.skinning_plus_blendshape, g.blendshape)
    assert 0.003 < np.linalg.norm(g.blendshape - neutral, axis=1).max() < 0.05  # the brow, not the bones
    e = generator.pose(a, "elbowBentLf", "tpose")
    hand = np.linalg.norm(e.skinning_plus_blendshape - neutral, axis=1) > 0.10  # what the elbow flexion moves
    assert hand.sum() > 200
    assert np.linalg.norm(e.blendshape - neutral, axis=1)[hand].max() < 0.02  # shapes only: the forearm stays
    assert np.linalg.norm(e.skinning - e.skinning_plus_blendshape, axis=1).max() < 0.03  # only correctives apart


def test_a_corpus_stores_each_character_in_its_rest_and_one_class_per_person(tiny_corpus, generator):
    """The corpus rows of a rest character are its rig states in that rest; the identity classifier
    sees a person's characters as one class (rests are not identities)."""
    from latent_model.config import preset
    from latent_model.train.data import PhaseASampler

    c = tiny_corpus
    rest_chars = [i for i, s in enumerate(c.identities) if s.rest != "bind"]
    assert rest_chars and set(c.rests) >= {"bind", "tpose", "armsSides"}
    i = next(i for i in rest_chars if c.identities[i].split == "test")
    spec = c.identities[i]
    assert np.abs(c.vertices(c.state(i, None, "neutral")) - generator.neutral(spec)).max() < 1e-5
    assert np.abs(c.vertices(c.state(i, "elbowBentLf", "skinning_plus_blendshape"))
                  - generator.state(spec, "elbowBentLf", "skinning_plus_blendshape")).max() < 1e-5
    bind = c.identity_index(spec.person_id)
    assert np.abs(c.vertices(c.state(i, None, "neutral")) - c.vertices(c.state(bind, None, "neutral"))).max() > 0.1
    sampler = PhaseASampler(c, preset("tiny"), seed=0)
    classes = sampler.class_of
    assert set(classes) == set(c.split_indices("train")) and not set(classes) & set(c.split_indices("val"))
    assert len(set(classes.values())) == preset("tiny").model.n_identities == 3
    for j in classes:
        same = [k for k in classes if c.identities[k].person_id == c.identities[j].person_id]
        assert len(same) == 2 and len({classes[k] for k in same}) == 1
