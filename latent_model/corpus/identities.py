"""Identity sampling and the identity-level train/test split.

Identities span both sexes, statures 1.50-1.95 m, lean to heavy, low to high muscle and
varied heads and faces (anny phenotype + local-change sliders). Variety is measured, not
assumed: see `variety_stats` (median nearest-identity distance must reach >= 25 mm).
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
# Stylised (out-of-distribution) characters: exaggerated heads and limb proportions.
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
    split: str  # "train" | "test"
    phenotypes: dict[str, float]
    local_changes: dict[str, float]
    face_style: FaceStyle = field(default_factory=FaceStyle)
    stylised: bool = False

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "IdentitySpec":
        fs = dict(d.get("face_style", {}))
        if "wave" in fs:
            fs["wave"] = tuple(fs["wave"])
        return IdentitySpec(d["id"], d["split"], dict(d["phenotypes"]), dict(d["local_changes"]),
                            FaceStyle(**fs), bool(d.get("stylised", False)))


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
