"""The latent bank: frozen-encoder means of the training states, standardisation statistics and
pose deltas per (pair kind, pose, training identity). Computed once, saved, reused by the
Transfer API, the evaluation and the explorer.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from safetensors.numpy import load_file, save_file

from latent_model.atomic import atomic_write
from latent_model.corpus.pairs import enumerate_pairs
from latent_model.types import PAIR_KINDS
from latent_model.corpus.store import Corpus
from latent_model.encoding import encode_states
from latent_model.errors import UserFacingError

BANK_FORMAT = 3  # 3: unique latent rows, standardised, in half precision + (source, target) indices per delta
READABLE_FORMATS = ("2", "3")  # 2: the rows in single precision


class BankError(UserFacingError, RuntimeError):
    pass


@dataclass
class LatentBank:
    """mu (N, Z) of training states; `keys[i]` = "ID/POSE/VARIANT"; standardisation mean/scale (Z,);
    deltas[(kind, pose)] = (identity ids, (n, Z) raw deltas mu_target - mu_source)."""

    mu: np.ndarray
    keys: list[str]
    mean: np.ndarray
    scale: np.ndarray
    deltas: dict[tuple[str, str], tuple[list[str], np.ndarray]]
    sources: dict[tuple[str, str], np.ndarray]  # (kind, pose) -> (n, Z) source means (for nearest identity)
    model_digest: str
    # (kind, pose) -> (source state indices, target state indices) into `mu`/`keys`
    pair_index: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] | None = None
    # median standardised distance between the means of two independent SDF samplings of the
    # same geometry: how long a delta made of sampling noise alone is (0 = not measured)
    noise_floor: float = 0.0
    # out-of-distribution threshold: the largest `distance_to_training` of a validation character's
    # neutral state (characters the model never trained on but that it serves; 0 = not calibrated)
    ood_threshold: float = 0.0
    # the same for a posed source (skinned, shaped, a combo's component: the other pair kinds' sources): the
    # largest distance of a validation character's posed states, farther than its neutral (0 = not calibrated)
    ood_threshold_posed: float = 0.0
    _source_index: dict = field(default_factory=dict, repr=False, compare=False)  # (kind, pose) -> NearestNeighbors
    _std_rows: np.ndarray | None = field(default=None, repr=False, compare=False)  # standardised mu, on first use
    _std_norms: np.ndarray | None = field(default=None, repr=False, compare=False)  # their squared lengths

    def standardise(self, mu: np.ndarray) -> np.ndarray:
        return (mu - self.mean) / self.scale

    def threshold_for(self, kind: str) -> float:
        """The out-of-distribution threshold of a source of pair kind `kind` (its own, when calibrated)."""
        if kind != "neutral_to_pose" and self.ood_threshold_posed > 0:
            return self.ood_threshold_posed
        return self.ood_threshold

    def poses(self, kind: str = "neutral_to_pose") -> list[str]:
        return [p for k, p in self.deltas if k == kind]

    def delta(self, kind: str, pose: str) -> tuple[list[str], np.ndarray]:
        try:
            return self.deltas[(kind, pose)]
        except KeyError:
            valid = ", ".join(self.poses(kind)) or "(none)"
            raise KeyError(f"no {kind} delta for pose {pose!r} in the latent bank; poses: {valid}") from None

    def mean_delta(self, kind: str, pose: str) -> np.ndarray:
        """Delta averaged over training identities (the paper's mean_pose_delta)."""
        return self.delta(kind, pose)[1].mean(axis=0)

    def nearest_identity(self, kind: str, pose: str, mu_source: np.ndarray) -> tuple[str, np.ndarray]:
        """(identity, its delta) of the training identity whose source state is nearest to
        `mu_source` in standardised latent space (nearest_identity_delta)."""
        ids, d = self.delta(kind, pose)
        index = self._source_index.get((kind, pose))
        if index is None:
            from sklearn.neighbors import NearestNeighbors

            # exact distances (a tree, not the dot-product shortcut of brute force): the nearest is stable
            index = NearestNeighbors(n_neighbors=1, algorithm="ball_tree").fit(self.standardise(self.sources[(kind, pose)]))
            self._source_index[(kind, pose)] = index
        k = int(index.kneighbors(self.standardise(np.asarray(mu_source))[None], return_distance=False)[0, 0])
        return ids[k], d[k]

    def distance_to_training(self, mu: np.ndarray) -> float:
        """Standardised distance from a latent (Z,) to the nearest training state of the bank."""
        x = self.standardise(np.asarray(mu, np.float64))
        if self._std_rows is None:
            self._std_rows = self.standardise(self.mu.astype(np.float64))
            self._std_norms = (self._std_rows ** 2).sum(axis=1)
        # |r - x|^2 = |r|^2 - 2 r.x + |x|^2: one matrix-vector product (25 ms -> ~3 ms over 27k rows)
        d2 = self._std_norms - 2.0 * (self._std_rows @ x) + float(x @ x)
        return float(np.sqrt(max(float(d2.min()), 0.0)))

    def identity_delta(self, kind: str, pose: str, identity: str) -> np.ndarray:
        ids, d = self.delta(kind, pose)
        if identity not in ids:
            raise KeyError(f"identity {identity!r} is not a training identity of the bank; valid: {', '.join(ids)}")
        return d[ids.index(identity)]

    # ------------------------------------------------------------------ io
    def save(self, path: Path) -> None:
        """Unique latent rows (states sharing a geometry share a row) + per-delta index pairs:
        deltas are rebuilt exactly (the same float32 subtraction) on load."""
        if self.pair_index is None:
            raise BankError("this bank has no pair index (built by an older version); rebuild it with `lrr bank`")
        uniq, inverse = np.unique(self.mu.astype(np.float32), axis=0, return_inverse=True)
        inverse = inverse.reshape(-1).astype(np.int32)
        mean, scale = self.mean.astype(np.float32), self.scale.astype(np.float32)
        tensors = {"rows16": ((uniq - mean) / scale).astype(np.float16), "state_row": inverse, "mean": mean,
                   "scale": scale}
        index = []
        for n, ((kind, pose), (ids, _)) in enumerate(self.deltas.items()):
            src, tgt = self.pair_index[(kind, pose)]
            tensors[f"src{n}"] = np.asarray(src, np.int32)
            tensors[f"tgt{n}"] = np.asarray(tgt, np.int32)
            index.append({"kind": kind, "pose": pose, "ids": ids})
        meta = {"format": str(BANK_FORMAT), "keys": json.dumps(self.keys), "index": json.dumps(index),
                "model_digest": self.model_digest, "noise_floor": repr(float(self.noise_floor)),
                "ood_threshold": repr(float(self.ood_threshold)),
                "ood_threshold_posed": repr(float(self.ood_threshold_posed))}
        atomic_write(path, lambda tmp: save_file(tensors, str(tmp), metadata=meta))

    @staticmethod
    def load(path: Path) -> "LatentBank":
        from safetensors import safe_open

        path = Path(path)
        if not path.exists():
            raise BankError(f"latent bank {path} does not exist; build it with `lrr bank --checkpoint ...`")
        try:
            with safe_open(str(path), framework="np") as f:
                meta = f.metadata() or {}
            t = load_file(str(path))
        except Exception as e:  # noqa: BLE001 - any unreadable file is reported the same way
            raise BankError(f"latent bank {path} is corrupt ({e}); rebuild it with `lrr bank`") from e
        if meta.get("format") not in READABLE_FORMATS:
            raise BankError(f"latent bank {path} has format {meta.get('format')}, expected {BANK_FORMAT}; rebuild it")
        index = json.loads(meta["index"])
        rows = t["rows"] if "rows" in t else t["rows16"].astype(np.float32) * t["scale"] + t["mean"]
        mu = rows[t["state_row"]]
        deltas, sources, pair_index = {}, {}, {}
        for n, e in enumerate(index):
            key = (e["kind"], e["pose"])
            src, tgt = t[f"src{n}"].astype(np.int64), t[f"tgt{n}"].astype(np.int64)
            deltas[key] = (e["ids"], mu[tgt] - mu[src])
            sources[key] = mu[src]
            pair_index[key] = (src, tgt)
        return LatentBank(mu, json.loads(meta["keys"]), t["mean"], t["scale"], deltas, sources,
                          meta.get("model_digest", ""), pair_index, float(meta.get("noise_floor", 0.0)),
                          float(meta.get("ood_threshold", 0.0)), float(meta.get("ood_threshold_posed", 0.0)))


def half_precision(mu: np.ndarray, mean: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(N, Z) latents as the bank stores them: standardised, rounded to half precision (~1e-3 of a standard
    deviation per dimension, far under the noise floor), back in latent units; what keeps the bank of 112
    training characters within the 60 MB asset budget."""
    z = ((np.asarray(mu, np.float32) - mean) / scale).astype(np.float16)
    return (z.astype(np.float32) * scale + mean).astype(np.float32)


def model_digest(model: torch.nn.Module) -> str:
    """Hash of the encoder weights: a bank belongs to one encoder."""
    h = hashlib.sha256()
    for k, v in sorted(model.encoder.state_dict().items()):
        h.update(k.encode())
        h.update(v.detach().cpu().numpy().tobytes())
    return h.hexdigest()[:16]


def build_bank(model, corpus: Corpus, device: torch.device | None = None, progress: bool = True) -> LatentBank:
    """Encode every training state once and tabulate deltas for every pair kind and pose."""
    train = corpus.split_indices("train")
    states = [s for s in range(len(corpus.states)) if int(corpus.states[s, 0]) in set(train)]
    # one encoding per geometry row (face-only poses share rows)
    rows = sorted({corpus.row(s) for s in states})
    row_state = {}
    for s in states:
        row_state.setdefault(corpus.row(s), s)
    mu_rows = encode_states(model, corpus, [row_state[r] for r in rows], device, progress=progress)
    mu_of_row = {r: mu_rows[k] for k, r in enumerate(rows)}
    mu = np.stack([mu_of_row[corpus.row(s)] for s in states])
    keys = [corpus.state_name(s) for s in states]
    mean = mu.mean(axis=0).astype(np.float32)
    scale = (mu.std(axis=0) + 1e-6).astype(np.float32)
    mu = half_precision(mu, mean, scale)  # as stored: a loaded bank equals the built one
    deltas: dict = {}
    sources: dict = {}
    pair_index: dict = {}
    position = {s: k for k, s in enumerate(states)}
    pairs = enumerate_pairs(train, corpus.poses, PAIR_KINDS)
    grouped: dict[tuple[str, str], list] = {}
    for p in pairs:
        grouped.setdefault((p.kind, p.bank_key), []).append(p)
    for key, ps in grouped.items():
        ids, si, ti = [], [], []
        for p in ps:
            si.append(position[corpus.state(p.identity, p.source[0], p.source[1])])
            ti.append(position[corpus.state(p.identity, p.target[0], p.target[1])])
            ids.append(corpus.identities[p.identity].id)
        si, ti = np.asarray(si), np.asarray(ti)
        deltas[key] = (ids, mu[ti] - mu[si])
        sources[key] = mu[si]
        pair_index[key] = (si, ti)
    bank = LatentBank(mu, keys, mean, scale, deltas, sources, model_digest(model), pair_index)
    bank.noise_floor = measure_noise_floor(model, corpus, bank, device, progress=progress)
    bank.ood_threshold = calibrate_ood_threshold(model, corpus, bank, device, progress=progress)
    bank.ood_threshold_posed = calibrate_posed_threshold(model, corpus, bank, device, progress=progress)
    return bank


def calibrate_ood_threshold(model, corpus: Corpus, bank: LatentBank, device: torch.device | None = None,
                            progress: bool = False) -> float:
    """The largest distance to the training states of any validation character's neutral state (0 when
    the corpus has no validation split): a mesh farther than that is unlike anything validated."""
    val = corpus.split_indices("val")
    if not val:
        return 0.0
    mu = encode_states(model, corpus, [corpus.state(i, None, "neutral") for i in val], device, progress=progress)
    return float(max(bank.distance_to_training(m) for m in mu))


def calibrate_posed_threshold(model, corpus: Corpus, bank: LatentBank, device: torch.device | None = None,
                              progress: bool = False) -> float:
    """The largest distance to the training states of any validation character's posed source state (every state
    another pair kind than neutral_to_pose starts from; 0 without a validation split). A posed body lies farther
    from the training states than its neutral (validation: 1.5x), so the neutral threshold called every posed
    held-out character novel."""
    val = corpus.split_indices("val")
    if not val:
        return 0.0
    kinds = tuple(k for k in PAIR_KINDS if k != "neutral_to_pose")
    states = sorted({corpus.state(p.identity, *p.source) for p in enumerate_pairs(val, corpus.poses, kinds)})
    if not states:
        return 0.0
    mu = encode_states(model, corpus, states, device, progress=progress)
    return float(max(bank.distance_to_training(m) for m in mu))


NOISE_FLOOR_IDENTITIES = 32


def measure_noise_floor(model, corpus: Corpus, bank: LatentBank, device: torch.device | None = None,
                        progress: bool = False) -> float:
    """Median standardised distance between the means of two independent SDF re-samplings
    (resample 1 and 2) of the neutral state of up to 32 training identities."""
    train = corpus.split_indices("train")[:NOISE_FLOOR_IDENTITIES]
    states = [corpus.state(i, None, "neutral") for i in train]
    a = bank.standardise(encode_states(model, corpus, states, device, resample=1, progress=progress))
    b = bank.standardise(encode_states(model, corpus, states, device, resample=2, progress=progress))
    return float(np.median(np.linalg.norm(a - b, axis=1)))
