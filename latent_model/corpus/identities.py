"""Identity sampling, the person-level train/val/test split and characters (person x rest).

Persons span both sexes, statures 1.50-1.95 m, lean to heavy, low to high muscle and varied
heads and faces (anny phenotype + local-change sliders). Variety is measured, not assumed: see
`variety_stats` (median nearest-identity distance must reach >= 25 mm).

A corpus identity is a *character*: one person standing in one rest configuration (rests.py).
Every person has its bind-rest character (id ``id007``, at the index the person had before rests
existed, so its truth and SDF seeds are unchanged); a person's other characters are
``id007@tpose``... A split is a split of persons: all characters of a person share it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

# Local-change families sampled for ordinary identities (prefixes of anny's slider labels).
_FAMILIES = (
    "head-", "forehead-", "nose-", "chin-", "mouth-", "eyebrows-", "l-eye-", "l-ear-",
    "l-cheek-", "neck-", "measure-neck", "torso-", "measure-", "hip-", "stomach-",
    "buttocks-", "breast-", "l-upperarm-", "l-lowerarm-", "l-upperleg-", "l-lowerleg-",
    "l-hand-", "l-foot-", "upperlegs-", "lowerlegs-",
)
# Stylised (out-of-distribution) test characters: exaggerated heads and limb proportions.
_STYLISED = (
    {"head-scale-vert-incr": 1.0, "head-scale-horiz-incr": 1.0, "head-scale-depth-incr": 1.0,
     "measure-upperarm-length-incr": -0.8, "measure-lowerarm-length-incr": -0.8,
     "upperlegs-height-incr": -0.8, "lowerlegs-height-incr": -0.8, "nose-scale-horiz-incr": 0.8,
     "chin-prominent-incr": 0.8, "l-hand-scale-incr": 0.8, "r-hand-scale-incr": 0.8},
    {"head-scale-vert-incr": -0.7, "head-scale-horiz-incr": -0.9, "measure-neck-height-incr": 1.0,
     "measure-upperarm-length-incr": 1.0, "measure-lowerarm-length-incr": 1.0,
     "upperlegs-height-incr": 1.0, "lowerlegs-height-incr": 1.0, "torso-vshape-incr": 1.0,
     "nose-scale-vert-incr": 1.0, "l-ear-scale-incr": 1.0, "r-ear-scale-incr": 1.0},
)


# Families a stylised *training* recipe draws from (labels, sign-free: the sign is drawn per recipe).
_STYLE_FAMILIES: tuple[tuple[str, ...], ...] = (
    ("head-scale-vert-incr", "head-scale-horiz-incr", "head-scale-depth-incr"),  # big or small head
    ("measure-upperarm-length-incr", "measure-lowerarm-length-incr"),  # long or short arms
    ("upperlegs-height-incr", "lowerlegs-height-incr"),  # long or short legs
    ("torso-scale-horiz-incr", "torso-scale-depth-incr", "stomach-pregnant-incr"),  # heavy or slight torso
    ("l-hand-scale-incr", "r-hand-scale-incr"),
    ("measure-neck-height-incr",),
    ("torso-vshape-incr", "hip-scale-horiz-incr"),
)
MIN_RECIPE_DISTANCE = 1.0  # slider-space L2 a training recipe keeps from each test recipe


def recipe_distance(a: dict[str, float], b: dict[str, float]) -> float:
    """L2 distance of two local-change recipes over the union of their sliders (absent = 0)."""
    keys = set(a) | set(b)
    return float(np.sqrt(sum((a.get(k, 0.0) - b.get(k, 0.0)) ** 2 for k in keys)))


def stylised_recipe(rng: np.random.Generator) -> dict[str, float]:
    """A seeded stylised recipe: 3-4 families pushed to 0.6-1.0 of a slider, none close to a test recipe."""
    while True:
        out: dict[str, float] = {}
        for f in sorted(rng.choice(len(_STYLE_FAMILIES), size=int(rng.integers(3, 5)), replace=False)):
            value = float(rng.choice((-1.0, 1.0)) * rng.uniform(0.6, 1.0))
            out.update({label: round(value, 3) for label in _STYLE_FAMILIES[f]})
        if min(recipe_distance(out, t) for t in _STYLISED) >= MIN_RECIPE_DISTANCE:
            return out


@dataclass(frozen=True)
class FaceStyle:
    """Per-identity 'sculpting' style of the facial shapes (see `face.py`)."""

    intensity: float = 1.0  # overall gain
    spread: float = 0.0  # >0 widens the shapes (blend toward a smoothed field), <0 sharpens
    asymmetry: float = 0.0  # left/right gain difference
    wave: tuple[float, float, float, float] = (0.0, 0.1, 0.0, 0.0)  # (amplitude, wavelength m, azimuth rad, phase)


@dataclass(frozen=True)
class IdentitySpec:
    """Everything needed to regenerate an identity through the rig (JSON-serialisable)."""

    id: str
    split: str  # "train" | "val" | "test" (the person's)
    phenotypes: dict[str, float]
    local_changes: dict[str, float]
    face_style: FaceStyle = field(default_factory=FaceStyle)
    stylised: bool = False
    rest: str = "bind"  # the rest configuration this character stands in (rests.py)
    person: str = ""  # the person it is ("" = its own id: the person's bind character)

    @property
    def person_id(self) -> str:
        return self.person or self.id

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "IdentitySpec":
        fs = dict(d.get("face_style", {}))
        if "wave" in fs:
            fs["wave"] = tuple(fs["wave"])
        return IdentitySpec(d["id"], d["split"], dict(d["phenotypes"]), dict(d["local_changes"]),
                            FaceStyle(**fs), bool(d.get("stylised", False)), d.get("rest", "bind"), d.get("person", ""))


def _mirror_label(label: str) -> str | None:
    if label.startswith("l-"):
        return "r-" + label[2:]
    return None


def _sample_local_changes(rng: np.random.Generator, labels: list[str], n: int) -> dict[str, float]:
    pool = [lab for lab in labels if lab.startswith(_FAMILIES)]
    chosen = rng.choice(len(pool), size=min(n, len(pool)), replace=False)
    out: dict[str, float] = {}
    for i in sorted(chosen):
        label = pool[i]
        value = float(np.clip(rng.normal(0.0, 0.55), -1.0, 1.0))
        out[label] = round(value, 3)
        twin = _mirror_label(label)
        if twin in labels:  # bilateral features stay (nearly) symmetric
            out[twin] = round(float(np.clip(value + rng.normal(0.0, 0.05), -1.0, 1.0)), 3)
    return out


def _face_style(rng: np.random.Generator) -> FaceStyle:
    return FaceStyle(
        intensity=round(float(rng.uniform(0.75, 1.25)), 3),
        spread=round(float(rng.uniform(-0.6, 1.0)), 3),
        asymmetry=round(float(rng.uniform(-0.2, 0.2)), 3),
        wave=(round(float(rng.uniform(0.10, 0.25)), 3), round(float(rng.uniform(0.05, 0.10)), 3),
              round(float(rng.uniform(0, np.pi)), 3), round(float(rng.uniform(0, 2 * np.pi)), 3)),
    )


def sample_identities(n: int, n_test: int, n_stylised: int, seed: int,
                      local_change_labels: list[str]) -> list[IdentitySpec]:
    """`n` identities (ids id000..), `n_test` held out (the stylised ones among them)."""
    if not 0 <= n_stylised <= n_test < n:
        raise ValueError(f"need 0 <= n_stylised ({n_stylised}) <= n_test ({n_test}) < n ({n})")
    rng = np.random.default_rng(seed)
    n_plain = n - n_stylised
    # Stratify stature and sex so both span their full ranges even for small n.
    statures = 1.50 + 0.45 * (rng.permutation(n_plain) + rng.uniform(0, 1, n_plain)) / n_plain
    specs: list[dict] = []
    for i in range(n_plain):
        male = i % 2 == 0
        stature = float(statures[i])
        if not male:
            stature = 1.52 + (stature - 1.50) * 0.28 / 0.45  # women 1.52-1.80 m
        else:
            stature = 1.60 + (stature - 1.50) * 0.33 / 0.45  # men 1.60-1.93 m
        height = (stature - (1.354 if male else 1.22)) / 1.09
        phen = {
            "gender": float(rng.uniform(0.8, 1.0) if male else rng.uniform(0.0, 0.2)),
            "age": float(rng.uniform(0.72, 0.95)),
            "muscle": float(rng.uniform(0.0, 1.0)),
            "weight": float(rng.uniform(0.0, 1.0)),
            "height": float(np.clip(height, 0.0, 1.0)),
            "proportions": float(rng.uniform(0.0, 1.0)),
        }
        specs.append({"phenotypes": {k: round(v, 3) for k, v in phen.items()},
                      "local_changes": _sample_local_changes(rng, local_change_labels, 40),
                      "stylised": False})
    for j in range(n_stylised):
        phen = {"gender": 1.0 if j % 2 == 0 else 0.0, "age": 0.8, "muscle": 0.5, "weight": 0.5,
                "height": 0.4, "proportions": 0.5}
        specs.append({"phenotypes": phen, "local_changes": dict(_STYLISED[j % len(_STYLISED)]),
                      "stylised": True})
    # Split: stylised identities are always held out; the rest of the test set is random.
    plain_test = set(rng.choice(n_plain, size=n_test - n_stylised, replace=False).tolist())
    out = []
    for i, s in enumerate(specs):
        split = "test" if (s["stylised"] or i in plain_test) else "train"
        out.append(IdentitySpec(f"id{i:03d}", split, s["phenotypes"], s["local_changes"],
                                _face_style(rng), s["stylised"]))
    return out


def characters(persons: list[IdentitySpec], seed: int, n_val: int = 0, n_stylised_train: int = 0,
               train_rests: int = 0, val_rests: tuple[str, ...] = (), test_rests: tuple[str, ...] = ()
               ) -> list[IdentitySpec]:
    """The corpus identities of sampled persons: every person's bind character first (same order and
    index as the persons), then the other rests' characters.

    Among the non-test persons, `n_stylised_train` get a seeded stylised recipe on top of their own
    sliders (one of them, and `n_val` - 1 plain ones, go to validation). Each training person also
    stands in `train_rests` of the non-bind training rests (a balanced seeded cycle), each validation
    person in one of `val_rests` (alternating), each test person in all `test_rests`.
    """
    from latent_model.corpus.rests import TRAIN_RESTS, get_rest

    for name in (*val_rests, *test_rests):
        get_rest(name)
    rng = np.random.default_rng([seed, 4])  # its own stream: the persons stay as they were sampled
    train = [i for i, p in enumerate(persons) if p.split == "train"]
    if not 0 <= n_stylised_train <= len(train) or not 0 <= n_val <= len(train) - 1:
        raise ValueError(f"need 0 <= n_stylised_train ({n_stylised_train}) <= {len(train)} training persons "
                         f"and n_val ({n_val}) < {len(train)}")
    styled = sorted(rng.choice(train, size=n_stylised_train, replace=False).tolist())
    plain = [i for i in train if i not in styled]
    val = (styled[:1] if n_val else []) + sorted(rng.choice(plain, size=max(0, n_val - bool(styled)), replace=False).tolist())
    out = []
    for i, p in enumerate(persons):
        changes, stylised = p.local_changes, p.stylised
        if i in styled:
            changes, stylised = {**p.local_changes, **stylised_recipe(rng)}, True
        out.append(IdentitySpec(p.id, "val" if i in val else p.split, p.phenotypes, changes, p.face_style, stylised))
    extra = [r for r in TRAIN_RESTS if not get_rest(r).is_bind]
    if train_rests > len(extra):
        raise ValueError(f"train_rests ({train_rests}) exceeds the {len(extra)} non-bind training rests")
    cycle = [extra[k] for k in rng.permutation(len(extra))]
    n_train = 0
    for i, b in enumerate(list(out)):
        if b.split == "train":
            mine = [cycle[(n_train * train_rests + k) % len(cycle)] for k in range(train_rests)]
            n_train += 1
        elif b.split == "val":
            mine = [val_rests[val.index(i) % len(val_rests)]] if val_rests else []
        else:
            mine = list(test_rests)
        out.extend(IdentitySpec(f"{b.id}@{r}", b.split, b.phenotypes, b.local_changes, b.face_style, b.stylised,
                                r, b.id) for r in mine)
    return out


def variety_stats(rest_vertices: np.ndarray) -> dict[str, float]:
    """Shape variety of neutral meshes (N, V, 3), pelvis-aligned (anny's origin is the pelvis).

    Distance between two identities = mean per-vertex Euclidean distance (m)."""
    N = len(rest_vertices)
    D = np.zeros((N, N))
    for i in range(N):
        D[i] = np.linalg.norm(rest_vertices - rest_vertices[i], axis=2).mean(axis=1)
    off = D[~np.eye(N, dtype=bool)]
    nearest = np.where(np.eye(N, dtype=bool), np.inf, D).min(axis=1)
    return {
        "nearest_median_mm": float(np.median(nearest) * 1000),
        "nearest_min_mm": float(nearest.min() * 1000),
        "pairwise_median_mm": float(np.median(off) * 1000),
        "pairwise_max_mm": float(off.max() * 1000),
    }
