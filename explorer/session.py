"""The explorer's session model, free of Qt: selections -> predictions through the Transfer API,
error/displacement colours, heatmap data, the noise floor, JSON save/load and the coalescing of
slider updates. The window is a thin view over this (and tests drive it without a display).
"""
from __future__ import annotations

import json
import threading
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Callable, Generic, TypeVar

import numpy as np

from latent_model.corpus.sdf import vertex_normals
from latent_model.meshio import UserMesh, export_mesh, from_identity, load_mesh

SESSION_FORMAT = 1
ERROR_RANGE_MM = (0.0, 40.0)  # fixed colour range of per-vertex error (shared by every prediction view)
DISPLACEMENT_RANGE_MM = (0.0, 80.0)  # fixed colour range of |prediction - source|
STRATEGY_LABELS = {"mean_pose_delta": "mean pose delta", "nearest_identity_delta": "nearest identity delta"}
COMPARE_STRATEGIES = ("mean_pose_delta", "nearest_identity_delta")
NOISE_POSES = ("elbowBentLf", "elbowSuperBentLf", "kneeBentLf", "clavicleDownwardLf", "shoulderRaiseLf",
               "fingerKnuckleD03Lf", "fingerKnuckleD02Lf", "browDwLf", "puffLf", "cornerUpLf",
               "cornerPuckerLf", "cornerStretchLf", "jawOpen")


class SessionError(ValueError):
    """A selection or session file the user gave cannot be used (message says why and what to do)."""


# ----------------------------------------------------------------------------- selection
@dataclass
class Selection:
    """Everything the user chose: the state a session file stores."""

    target: str = "id008"
    kind: str = "neutral_to_pose"
    pose: str = "elbowBentLf"
    pose_b: str | None = None
    blend: float = 0.0  # 0 = pose A, 1 = pose B
    magnitude: float = 1.0  # scales r_delta, 0..2
    # mean_pose_delta | nearest_identity_delta | identity:<id>; mean by default: on held-out bodies it
    # transfers better than a single identity's delta on every broad body pose (README Results)
    strategy: str = "mean_pose_delta"
    colour: str = "error"  # error | displacement
    compare: bool = False
    wireframe: bool = False

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "Selection":
        if not isinstance(d, dict):
            raise SessionError("a selection must be a JSON object")
        names = {f.name for f in fields(Selection)}
        unknown = set(d) - names
        if unknown:
            raise SessionError(f"unknown selection fields {sorted(unknown)}; valid: {sorted(names)}")
        s = Selection(**d)
        s.blend = float(s.blend)
        s.magnitude = float(s.magnitude)
        if not 0.0 <= s.blend <= 1.0:
            raise SessionError(f"blend {s.blend} outside [0, 1]")
        if not 0.0 <= s.magnitude <= 2.0:
            raise SessionError(f"magnitude {s.magnitude} outside [0, 2]")
        if s.colour not in ("error", "displacement"):
            raise SessionError(f"colour {s.colour!r}: use error or displacement")
        return s


def save_session(path: str | Path, sel: Selection, meshes: dict[str, str] | None = None) -> Path:
    """Write the selection (and the paths of opened meshes) as JSON, atomically."""
    from latent_model.corpus.store import atomic_write_json

    path = Path(path)
    atomic_write_json(path, {"format": SESSION_FORMAT, "selection": sel.to_dict(), "meshes": meshes or {}})
    return path


def read_session(path: str | Path) -> tuple[Selection, dict[str, str]]:
    """(selection, {mesh name: file path}) of a session file."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise SessionError(f"{path}: no such session file") from None
    except (OSError, ValueError) as e:
        raise SessionError(f"{path}: not a readable session JSON ({e})") from None
    if not isinstance(d, dict) or d.get("format") != SESSION_FORMAT:
        raise SessionError(f"{path}: not an explorer session (format {SESSION_FORMAT} expected)")
    try:
        return Selection.from_dict(d["selection"]), dict(d.get("meshes", {}))
    except (KeyError, TypeError) as e:
        raise SessionError(f"{path}: broken session file ({e})") from None


# ----------------------------------------------------------------------------- coalescing
T = TypeVar("T")


class Coalescer(Generic[T]):
    """At most one request in flight and one waiting: a new request replaces the waiting one, so
    scrubbing a slider never queues work up. Thread-safe.

    submit(x) -> True when the caller should start work on x now (nothing in flight);
    done() -> the latest request that arrived meanwhile (start it now) or None (idle)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._busy = False
        self._pending: T | None = None
        self._has_pending = False
        self.dropped = 0  # requests replaced before they ran

    def submit(self, item: T) -> bool:
        with self._lock:
            if not self._busy:
                self._busy = True
                return True
            if self._has_pending:
                self.dropped += 1
            self._pending, self._has_pending = item, True
            return False

    def take(self) -> tuple[bool, T | None]:
        """Worker side: (True, item) to run next, or (False, None) and the coalescer goes idle."""
        with self._lock:
            if self._has_pending:
                item, self._pending, self._has_pending = self._pending, None, False
                return True, item
            self._busy = False
            return False, None

    def done(self) -> T | None:
        ok, item = self.take()
        return item if ok else None

    @property
    def busy(self) -> bool:
        return self._busy


# ----------------------------------------------------------------------------- results
@dataclass
class Prediction:
    """One prediction: model-frame arrays, all (V, 3) / (V,), with its error against the truth."""

    strategy: str
    label: str  # conditioning source: "mean" or an identity id
    vertices: np.ndarray
    error_mm: np.ndarray | None  # (V,) |pred - truth| in mm, None without truth
    displacement_mm: np.ndarray  # (V,) |pred - source| in mm
    normals: np.ndarray | None = None  # (V, 3) unit vertex normals for shading (computed off the UI thread)
    gate: float = 1.0  # the Transfer API's noise gate (1 = the decoder's output untouched)
    signal: float = float("inf")  # conditioning delta / latent noise floor

    @property
    def title(self) -> str:
        name = STRATEGY_LABELS.get(self.strategy, "identity " + self.strategy.split(":", 1)[-1])
        cond = f" ({self.label})" if self.strategy != "mean_pose_delta" and not self.strategy.startswith("identity:") else ""
        if self.error_mm is not None:
            text = f"{name}{cond}\nerror mean {self.error_mm.mean():.1f} / max {self.error_mm.max():.1f} mm"
        else:
            text = f"{name}{cond}\ndisplacement mean {self.displacement_mm.mean():.1f} / max {self.displacement_mm.max():.1f} mm"
        if self.gate < 1.0:
            text += f"\nnoise gate {self.gate:.2f}: delta at {self.signal:.1f}x the latent noise floor"
        return text


@dataclass
class ViewState:
    """What the three (or, comparing, four) views show for a selection."""

    selection: Selection
    target: str
    faces: np.ndarray  # (F, 3)
    source: np.ndarray  # (V, 3)
    truth: np.ndarray | None  # (V, 3) or None (an opened mesh has no ground truth)
    truth_title: str
    predictions: list[Prediction]  # one, or mean + nearest when comparing
    seconds: float = 0.0  # time of compute()
    seconds_decoder: float = 0.0  # of which inside Transfer.predict

    @property
    def prediction(self) -> Prediction:
        return self.predictions[0]

    @property
    def conditioning(self) -> str | None:
        """The identity whose delta conditioned the (first) prediction, if one did."""
        lab = self.prediction.label
        return None if lab in ("mean", "oracle") else lab


@dataclass
class HeatmapData:
    ids: list[str]  # row/column labels (training identities, then the target if it is not one)
    identity_distance: np.ndarray  # (n, n) standardised neutral-latent distances
    cosine_ids: list[str]  # training identities with a delta for the pose
    pose_cosine: np.ndarray  # (m, m) cosine of standardised deltas
    pose: str
    kind: str
    target: str
    conditioning: str | None


@dataclass
class NoiseFloor:
    """Per pose of one target: d_condition = |std(mu_pose) - std(mu_neutral)| and d_noise =
    |std(mu_pose, sampling a) - std(mu_pose, sampling b)| (two SDF resamplings of the same state)."""

    target: str
    poses: list[str] = field(default_factory=list)
    d_condition: list[float] = field(default_factory=list)
    d_noise: list[float] = field(default_factory=list)

    @property
    def ratios(self) -> np.ndarray:
        return np.asarray(self.d_condition) / (np.asarray(self.d_noise) + 1e-6)


# ----------------------------------------------------------------------------- the session
ProgressFn = Callable[[str, float | None], None]  # (message, fraction in [0, 1] or None = busy)


def _noop(msg: str, frac: float | None) -> None:
    pass


class Session:
    """Held-out identities (ground truth regenerated through the rig) and opened meshes, predicted
    through one `Transfer`. Not thread-safe: the window calls it from one worker thread."""

    def __init__(self, transfer, truth=None, test_ids: list[str] | None = None) -> None:
        self.transfer = transfer
        self.truth = truth  # latent_model.shipped.GroundTruth or None
        self.test_ids = list(test_ids or [])
        self.meshes: dict[str, UserMesh] = {}
        self._prepared: dict[tuple, object] = {}
        self._noise: dict[str, NoiseFloor] = {}

    # -------------------------------------------------------------- construction
    @classmethod
    def load_shipped(cls, progress: ProgressFn = _noop, root: Path | None = None, with_truth: bool = True) -> "Session":
        """The shipped model, bank and held-out identities (the slow part of a first launch:
        loading the model, and building anny's cache if this machine has none)."""
        from latent_model.shipped import ShippedPaths, load_identity_specs
        from latent_model.transfer import Transfer

        paths = ShippedPaths.at(root).check()
        progress("loading the model and latent bank", None)
        transfer = Transfer.from_files(paths.checkpoint, paths.bank)
        specs, _ = load_identity_specs(paths.identities)
        test_ids = [s.id for s in specs if s.split == "test"]
        s = cls(transfer, None, test_ids)
        if with_truth:
            progress("preparing the body model for ground truth (the first launch builds anny's cache: minutes)", None)
            s.attach_truth(paths.identities)
        return s

    def attach_truth(self, identities: Path | None = None) -> None:
        """Regenerate held-out ground truth through the rig from the identity specs (builds
        anny's cache on a machine that has none: minutes, once)."""
        from latent_model.shipped import GroundTruth, load_identity_specs

        specs, _ = load_identity_specs(identities)
        self.truth = GroundTruth(specs)
        self.test_ids = [s.id for s in specs if s.split == "test"]

    # -------------------------------------------------------------- choices
    @property
    def targets(self) -> list[str]:
        return (self.test_ids if self.truth is not None else []) + list(self.meshes)

    @property
    def training_ids(self) -> list[str]:
        seen: dict[str, None] = {}
        for k in self.transfer.bank.keys:
            seen.setdefault(k.split("/", 1)[0], None)
        return list(seen)

    def poses(self, kind: str = "neutral_to_pose") -> list[str]:
        return self.transfer.bank.poses(kind)

    def kinds(self) -> list[str]:
        from latent_model.corpus.pairs import PAIR_KINDS

        return [k for k in PAIR_KINDS if self.poses(k)]

    def has_truth(self, target: str) -> bool:
        return self.truth is not None and target in self.test_ids

    def validate(self, sel: Selection) -> Selection:
        """Raise SessionError with the valid choices when a selection names something unknown."""
        from latent_model.transfer import parse_strategy

        if sel.target not in self.targets:
            raise SessionError(f"unknown target {sel.target!r}; valid: {', '.join(self.targets)}")
        if sel.kind not in self.kinds():
            raise SessionError(f"unknown pair kind {sel.kind!r}; valid: {', '.join(self.kinds())}")
        poses = self.poses(sel.kind)
        for p in (sel.pose, sel.pose_b):
            if p is not None and p not in poses:
                raise SessionError(f"unknown pose {p!r} for {sel.kind}; valid: {', '.join(poses)}")
        s = parse_strategy(sel.strategy)
        if s == "oracle":
            raise SessionError("the oracle strategy is for the evaluation only; use mean, nearest or identity:<id>")
        if s.startswith("identity:") and s.split(":", 1)[1] not in self.training_ids:
            raise SessionError(f"{s}: not a training identity; valid: {', '.join(self.training_ids)}")
        if not self.has_truth(sel.target) and sel.kind != "neutral_to_pose":
            raise SessionError(f"an opened mesh ({sel.target}) is a source mesh: only neutral_to_pose applies to it")
        return sel

    # -------------------------------------------------------------- meshes
    def open_mesh(self, path: str | Path, up: str = "auto", units: str = "auto") -> str:
        """Load a user's mesh (MeshError on bad files) and add it to the targets; returns its name."""
        m = load_mesh(path, up=up, units=units)
        name = m.name
        k = 2
        while name in self.meshes or name in self.test_ids:
            name = f"{m.name} ({k})"
            k += 1
        m.name = name
        self.meshes[name] = m
        return name

    @staticmethod
    def _split_key(kind: str, pose: str) -> tuple[str, str | None]:
        """A bank pose key -> (pose, source component or None) (source_to_combo keys are 'combo<component>')."""
        if kind == "source_to_combo" and "<" in pose:
            p, comp = pose.split("<", 1)
            return p, comp
        return pose, None

    def source_mesh(self, target: str, kind: str, pose: str) -> UserMesh:
        """The source state of the pair (an opened mesh is its own source)."""
        if target in self.meshes:
            return self.meshes[target]
        if not self.has_truth(target):
            raise SessionError(f"unknown target {target!r}; valid: {', '.join(self.targets)}")
        p, comp = self._split_key(kind, pose)
        src, _ = self.truth.pair(target, kind, p, comp)
        return from_identity(src, self.truth.faces, target, self.truth.body_faces)

    def truth_state(self, target: str, kind: str, pose: str) -> np.ndarray | None:
        if not self.has_truth(target):
            return None
        p, comp = self._split_key(kind, pose)
        return self.truth.pair(target, kind, p, comp)[1]

    def _source_key(self, target: str, kind: str, pose: str) -> tuple:
        if target in self.meshes:
            return (target,)
        from latent_model.shipped import pair_states

        p, comp = self._split_key(kind, pose)
        return (target,) + pair_states(kind, p, comp)[0]

    def prepared(self, target: str, kind: str, pose: str):
        """Transfer.prepare of the pair's source (cached: encoding is the slow step)."""
        key = self._source_key(target, kind, pose)
        if key not in self._prepared:
            if len(self._prepared) > 64:
                self._prepared.clear()
            m = self.source_mesh(target, kind, pose)
            self._prepared[key] = self.transfer.prepare(m.vertices, m.faces, sdf_faces=m.sdf_faces)
        return self._prepared[key]

    # -------------------------------------------------------------- prediction
    def _predict(self, sel: Selection, strategy: str, prepared, source: np.ndarray,
                 truth: np.ndarray | None) -> tuple[Prediction, float]:
        t = time.perf_counter()
        pose_b = sel.pose_b if sel.blend > 0 else None
        out = self.transfer.predict_detail(prepared, sel.pose, strategy, sel.magnitude, sel.kind, pose_b, sel.blend)
        v = out.vertices
        dt = time.perf_counter() - t
        label = out.label
        err = None if truth is None else np.linalg.norm(v - truth, axis=1) * 1000.0
        disp = np.linalg.norm(v - source, axis=1) * 1000.0
        return Prediction(strategy, label, v, err, disp, vertex_normals(v, prepared.faces), out.gate, out.signal), dt

    def compute(self, sel: Selection) -> ViewState:
        """Everything the views show for a selection (the one path: Transfer.prepare + predict)."""
        from latent_model.transfer import parse_strategy

        t0 = time.perf_counter()
        self.validate(sel)
        prepared = self.prepared(sel.target, sel.kind, sel.pose)
        source = prepared.vertices
        truth = self.truth_state(sel.target, sel.kind, sel.pose)
        truth_title = "ground truth: none for an opened mesh" if truth is None else f"ground truth ({sel.pose})"
        if truth is not None and sel.pose_b is not None and sel.blend > 0:
            tb = self.truth_state(sel.target, sel.kind, sel.pose_b)
            truth = ((1.0 - sel.blend) * truth + sel.blend * tb).astype(np.float32)
            truth_title = f"reference: truth {sel.pose} -> {sel.pose_b} blended {sel.blend:.2f} linearly"
        strategies = COMPARE_STRATEGIES if sel.compare else (parse_strategy(sel.strategy),)
        preds, t_dec = [], 0.0
        for s in strategies:
            p, dt = self._predict(sel, s, prepared, source, truth)
            preds.append(p)
            t_dec += dt
        return ViewState(sel, sel.target, prepared.faces, source, truth, truth_title, preds,
                         time.perf_counter() - t0, t_dec)

    def export(self, state: ViewState, path: str | Path, which: int = 0) -> Path:
        """Write a prediction in the frame, units and vertex order of its source file."""
        mesh = self.source_mesh(state.target, state.selection.kind, state.selection.pose)
        return export_mesh(mesh, state.predictions[which].vertices, path)

    # -------------------------------------------------------------- heatmaps
    def neutral_latents(self) -> tuple[list[str], np.ndarray]:
        """(training ids, (n, Z) neutral latent means) from the bank."""
        bank = self.transfer.bank
        rows = {k.split("/", 1)[0]: i for i, k in enumerate(bank.keys) if k.endswith("/neutral")}
        ids = [i for i in self.training_ids if i in rows]
        return ids, bank.mu[[rows[i] for i in ids]]

    def target_neutral_mu(self, target: str) -> np.ndarray:
        return self.prepared(target, "neutral_to_pose", self.poses("neutral_to_pose")[0]).mu

    def heatmaps(self, sel: Selection, conditioning: str | None = None) -> HeatmapData:
        """Identity-distance matrix of standardised neutral latents (training identities + the
        target) and the pose-cosine matrix of the selected pose's standardised deltas."""
        from latent_model.analysis.metrics import pairwise_cosines

        bank = self.transfer.bank
        ids, mu = self.neutral_latents()
        if sel.target not in ids:
            ids = ids + [sel.target]
            mu = np.concatenate([mu, self.target_neutral_mu(sel.target)[None]])
        z = bank.standardise(mu)
        dist = np.linalg.norm(z[:, None] - z[None], axis=-1)
        cids, deltas = bank.delta(sel.kind, sel.pose)
        cos = pairwise_cosines(deltas / bank.scale)
        return HeatmapData(ids, dist, list(cids), cos, sel.pose, sel.kind, sel.target, conditioning)

    # -------------------------------------------------------------- noise floor
    def noise_floor_steps(self, target: str, poses: tuple[str, ...] = NOISE_POSES):
        """Generator: computes the noise floor of a held-out target pose by pose, yielding
        (fraction done, NoiseFloor so far); small and local (two SDF samplings per state)."""
        if not self.has_truth(target):
            raise SessionError(f"the noise floor needs a held-out identity with ground truth, not {target!r}")
        if target in self._noise:
            yield 1.0, self._noise[target]
            return
        bank = self.transfer.bank
        faces = self.truth.body_faces
        mu0 = self.target_neutral_mu(target)
        nf = NoiseFloor(target)
        poses = [p for p in poses if p in self.poses("neutral_to_pose")]
        for k, p in enumerate(poses):
            v = self.truth.state(target, p, "skinning_plus_blendshape")
            a = self.transfer.encode(v, faces, seed=101)
            b = self.transfer.encode(v, faces, seed=202)
            nf.poses.append(p)
            nf.d_condition.append(float(np.linalg.norm(bank.standardise(a) - bank.standardise(mu0))))
            nf.d_noise.append(float(np.linalg.norm(bank.standardise(a) - bank.standardise(b))))
            yield (k + 1) / len(poses), nf
        self._noise[target] = nf

    def noise_floor(self, target: str, poses: tuple[str, ...] = NOISE_POSES) -> NoiseFloor:
        out = None
        for _, out in self.noise_floor_steps(target, poses):
            pass
        return out
