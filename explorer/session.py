"""The explorer's session model, free of Qt: selections -> predictions through the Transfer API,
heatmap data, the noise floor, and the window's state (what is selected and shown, what is pending).
Its pieces: `selection.py` (what the user chose, the session file), `results.py` (typed results),
`events.py` (the observer), `coalescer.py` (slider updates).

The split follows napari's (`components/camera.py` / `_qt/widgets/qt_dims.py`): the model owns the
state and announces each change on an `Event`; the Qt views subscribe and only draw. Tests drive
the model without a display.

Two threads touch a `Session`, on separate parts of it:
- the model worker thread runs the compute side (`compute`, `heatmaps`, `noise_floor_steps`,
  `open_mesh`, `open_example_steps`, `export`): it fills caches and returns typed results
  (`Predicted`, `HeatmapData`, `NoiseFloor`, `MeshOpened`, `ExampleOpened`, `Exported`) and never
  writes the window state;
- the UI thread writes the window state, only through `select`, `condition`, `apply(result)`,
  `restore` and `begin_noise`, and the events fire there. The structures both sides read, `meshes`
  and `examples`, are guarded by locks.

An example pair (A, A1) conditions a prediction the way a pose does: the selection names it
(`Selection.example`), its delta mu(A1) - mu(A) replaces pose A's, and the magnitude and blend
sliders act on it as on a pose's.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from functools import singledispatchmethod
from pathlib import Path
from collections.abc import Generator
from typing import Callable, NamedTuple

import numpy as np

from latent_model.corpus.pairs import pair_states, split_bank_key
from latent_model.corpus.sdf import vertex_normals
from latent_model.facing import face_front
from latent_model.meshio import UserMesh, export_mesh, from_identity, load_mesh
from latent_model.types import FINAL, PAIR_KINDS, PairKind

from explorer.events import Event
from explorer.example_pair import ExamplePairs, Progress, read_example_steps
from explorer.framing import example_offset, frame
from explorer.results import (ExampleOpened, ExamplePair, Exported, Failed, HeatmapData, HeatmapRequest, MeshOpened,
                              NoiseFloor, PairRef, Predicted, Prediction, ViewState, example_subject)
from explorer.selection import Selection, SessionError

COMPARE_STRATEGIES = ("mean_pose_delta", "nearest_identity_delta")
NOISE_POSES = ("elbowBentLf", "elbowSuperBentLf", "kneeBentLf", "clavicleDownwardLf", "shoulderRaiseLf",
               "fingerKnuckleD03Lf", "fingerKnuckleD02Lf", "browDwLf", "puffLf", "cornerUpLf",
               "cornerPuckerLf", "cornerStretchLf", "jawOpen")


# ----------------------------------------------------------------------------- the session
ProgressFn = Callable[[str, float | None], None]  # (message, fraction in [0, 1] or None = busy)


def _noop(msg: str, frac: float | None) -> None:
    pass


@dataclass
class SessionEvents:
    """What the views subscribe to (each fires on the UI thread, from `select`/`apply`/`restore`)."""

    selection: Event[Selection] = field(default_factory=lambda: Event("selection"))  # controls show it, worker computes it
    state: Event[ViewState] = field(default_factory=lambda: Event("state"))  # a new prediction is the one shown
    heatmaps_wanted: Event[HeatmapRequest] = field(default_factory=lambda: Event("heatmaps_wanted"))
    heatmaps: Event[HeatmapData] = field(default_factory=lambda: Event("heatmaps"))
    noise: Event[NoiseFloor] = field(default_factory=lambda: Event("noise"))
    mesh_opened: Event[MeshOpened] = field(default_factory=lambda: Event("mesh_opened"))
    example_opened: Event[ExampleOpened] = field(default_factory=lambda: Event("example_opened"))
    exported: Event[Exported] = field(default_factory=lambda: Event("exported"))
    failed: Event[Failed] = field(default_factory=lambda: Event("failed"))


class ToOpen(NamedTuple):
    """What a restored session needs opened before its selection is selected."""

    meshes: dict[str, str]  # mesh name -> file
    examples: dict[str, tuple[str, str]]  # example pair name -> (file of A, file of A1)


class Session:
    """Held-out identities (ground truth regenerated through the rig) and opened meshes, predicted
    through one `Transfer`, and the window's state over them (see the module docstring for which
    thread touches what)."""

    def __init__(self, transfer, truth=None, test_ids: list[str] | None = None) -> None:
        self.transfer = transfer
        self.truth = truth  # latent_model.shipped.GroundTruth or None
        self.test_ids = list(test_ids or [])
        self.meshes: dict[str, UserMesh] = {}
        self.examples = ExamplePairs()  # example pairs read and encoded (thread-safe itself)
        self._meshes_lock = threading.Lock()
        self._prepared: dict[tuple, object] = {}
        self._noise: dict[str, NoiseFloor] = {}
        self._example_masks: dict[tuple, dict[str, np.ndarray] | None] = {}  # (pair name, file stamp) -> A's regions
        # window state: written on the UI thread only
        self.events = SessionEvents()
        self.selection: Selection | None = None  # the latest selection asked for
        self.state: ViewState | None = None  # the prediction shown
        self.heatmap_key: tuple | None = None  # HeatmapRequest.key of the heatmaps shown or coming
        self.heatmaps_pending = False
        self.heatmap_data: HeatmapData | None = None
        self.noise: NoiseFloor | None = None  # the noise floor shown
        self.noise_for: str | None = None  # the target whose noise floor is being computed
        self.mesh_paths: dict[str, str] = {}  # opened mesh name -> its file (saved in session files)
        self.example_paths: dict[str, tuple[str, str]] = {}  # example pair name -> (file of A, of A1)
        self.pending_selection: Selection | None = None  # a restored selection waiting for its meshes
        self._pending_paths: set[str] = set()  # mesh paths and example subjects it waits for
        self._pending_examples: dict[str, str] = {}  # example subject -> the name the saved selection gave it

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
        with self._meshes_lock:
            return (self.test_ids if self.truth is not None else []) + list(self.meshes)

    def is_mesh(self, target: str) -> bool:
        with self._meshes_lock:
            return target in self.meshes

    @property
    def training_ids(self) -> list[str]:
        seen: dict[str, None] = {}
        for k in self.transfer.bank.keys:
            seen.setdefault(k.split("/", 1)[0], None)
        return list(seen)

    def poses(self, kind: str = "neutral_to_pose") -> list[str]:
        return self.transfer.bank.poses(kind)

    def kinds(self) -> list[str]:
        return [k for k in PAIR_KINDS if self.poses(k)]

    def has_truth(self, target: str) -> bool:
        return self.truth is not None and target in self.test_ids

    def default_selection(self) -> Selection:
        """The default selection, on the first held-out identity if the default one is unknown."""
        sel = Selection()
        targets = self.targets
        if targets and sel.target not in targets:
            sel.target = targets[0]
        return sel

    def validate(self, sel: Selection) -> Selection:
        """Raise SessionError with the valid choices when a selection names something unknown."""
        sel = sel.checked()
        targets = self.targets
        if sel.target not in targets:
            raise SessionError(f"unknown target {sel.target!r}; valid: {', '.join(targets)}")
        if sel.kind not in self.kinds():
            raise SessionError(f"unknown pair kind {sel.kind!r}; valid: {', '.join(self.kinds())}")
        poses = self.poses(sel.kind)
        for p in (sel.pose, sel.pose_b):
            if p is not None and p not in poses:
                raise SessionError(f"unknown pose {p!r} for {sel.kind}; valid: {', '.join(poses)}")
        s = sel.strategy
        if s == "oracle":
            raise SessionError("the oracle strategy is for the evaluation only; use mean, nearest or identity:<id>")
        if s.startswith("identity:") and s.split(":", 1)[1] not in self.training_ids:
            raise SessionError(f"{s}: not a training identity; valid: {', '.join(self.training_ids)}")
        if sel.example is not None:
            self.example(sel.example)
            if sel.kind != "neutral_to_pose":
                raise SessionError("an example pair is a neutral -> posed deformation: only neutral_to_pose applies "
                                   "to it (clear the example to predict another pair kind)")
        return sel

    # -------------------------------------------------------------- meshes
    def open_mesh(self, path: str | Path, up: str = "auto", units: str = "auto",
                  kind: PairKind = "neutral_to_pose") -> str:
        """Load a user's mesh (MeshError on bad files), facing front (`facing.face_front`, for a source of pair kind
        `kind`), and add it to the targets; returns its name."""
        return self.add_mesh(face_front(self.transfer, load_mesh(path, up=up, units=units), kind, up_known=up != "auto"))

    def add_mesh(self, m: UserMesh) -> str:
        """Add a loaded mesh to the targets under a name no other target has; returns the name."""
        with self._meshes_lock:
            name, k = m.name, 2
            while name in self.meshes or name in self.test_ids:
                name = f"{m.name} ({k})"
                k += 1
            m.name = name
            self.meshes[name] = m
        return name

    def remove_mesh(self, name: str) -> None:
        """Drop an opened mesh that could not be prepared (it leaves the targets)."""
        with self._meshes_lock:
            self.meshes.pop(name, None)
        self._prepared = {k: v for k, v in self._prepared.items() if k[0] != name}

    # -------------------------------------------------------------- example pairs
    def example(self, name: str) -> ExamplePair:
        """A held example pair (SessionError naming the held ones when unknown)."""
        ex = self.examples.get(name)
        if ex is None:
            raise SessionError(f"unknown example pair {name!r}; open it with File > Condition on an example pair… "
                               f"(held: {', '.join(self.examples.names()) or 'none'})")
        return ex

    def open_example_steps(self, neutral: str | Path, posed: str | Path, up: str = "auto",
                           units: str = "auto") -> Generator[Progress, None, ExampleOpened]:
        """Generator (model worker): read and encode an example pair, yielding (message, fraction);
        returns `ExampleOpened`. The same two files, unchanged, are not encoded again. A bad file or an
        A1 that is not A deformed raises MeshError with the fix."""
        held = self.examples.find(neutral, posed)
        if held is None:
            held = self.examples.add((yield from read_example_steps(self.transfer, neutral, posed, up, units)))
        a, a1 = held.neutral, held.posed
        moved = np.linalg.norm(a1.vertices - a.vertices, axis=1).max() * 1000
        return ExampleOpened(held, example_subject(neutral, posed), f"{held.label} ({a.n_file_vertices} vertices, "
                             f"{len(a.file_faces)} triangles; A1 moves vertices by up to {moved:.0f} mm)")

    def open_example(self, neutral: str | Path, posed: str | Path, up: str = "auto",
                     units: str = "auto") -> ExampleOpened:
        """`open_example_steps` run to the end (scripts and tests)."""
        steps = self.open_example_steps(neutral, posed, up, units)
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return done.value

    def conditioned(self, sel: Selection, example: str | None) -> Selection:
        """`sel` conditioned on a held example pair, or back on its pose (`example` None). An example is
        a neutral -> posed deformation, so it predicts neutral_to_pose, one prediction (comparing mean
        and nearest is about pose strategies); pose B, if kept, is blended toward as usual."""
        if example is None:
            return replace(sel, example=None)
        poses = self.poses("neutral_to_pose")
        return replace(sel, example=example, kind="neutral_to_pose", compare=False,
                       pose=sel.pose if sel.pose in poses else poses[0],
                       pose_b=sel.pose_b if sel.pose_b in poses else None)

    def pair(self, target: str, kind: str, pose: str) -> PairRef:
        """The pair a selection names; `pose` is a bank pose key (source_to_combo: 'combo<component>')."""
        p, comp = split_bank_key(kind, pose)
        if self.is_mesh(target):
            return PairRef(target, kind, p, comp, None, None)
        if not self.has_truth(target):
            raise SessionError(f"unknown target {target!r}; valid: {', '.join(self.targets)}")
        src, goal = pair_states(kind, p, comp)
        return PairRef(target, kind, p, comp, src, goal)

    def source_mesh(self, pair: PairRef) -> UserMesh:
        """The source state of the pair (an opened mesh is its own source)."""
        if pair.source is None:
            with self._meshes_lock:
                return self.meshes[pair.target]
        v = self.truth.state(pair.target, *pair.source)
        return from_identity(v, self.truth.faces, pair.target, self.truth.body_faces)

    def truth_state(self, pair: PairRef) -> np.ndarray | None:
        """(V, 3) ground truth of the pair's goal state; None for an opened mesh."""
        return None if pair.goal is None else self.truth.state(pair.target, *pair.goal)

    def prepare(self, pair: PairRef):
        """Transfer.prepare of the pair's source (cached: encoding is the slow step)."""
        key = pair.cache_key
        if key not in self._prepared:
            if len(self._prepared) > 64:
                self._prepared.clear()
            m = self.source_mesh(pair)
            self._prepared[key] = self.transfer.prepare_user_mesh(m)
        return self._prepared[key]

    def prepared(self, target: str, kind: str = "neutral_to_pose", pose: str | None = None):
        """`prepare` of a target's pair (pose defaults to the kind's first)."""
        return self.prepare(self.pair(target, kind, pose or self.poses(kind)[0]))

    # -------------------------------------------------------------- prediction
    def _predict(self, sel: Selection, strategy: str, prepared, source: np.ndarray, truth: np.ndarray | None,
                 example: ExamplePair | None = None) -> tuple[Prediction, float]:
        t = time.perf_counter()
        pose_b = sel.pose_b if sel.blend > 0 else None
        if example is None:
            out = self.transfer.predict_detail(prepared, sel.pose, strategy, sel.magnitude, sel.kind, pose_b, sel.blend)
        else:  # the example's delta is pose A's; the strategy still gives pose B's when blending
            out = self.transfer.predict_detail(prepared, None, strategy, sel.magnitude, sel.kind, pose_b, sel.blend,
                                               delta=example.delta, detail_delta=example.detail,
                                               body_reading=example.body)
        v = out.vertices
        dt = time.perf_counter() - t
        err = None if truth is None else np.linalg.norm(v - truth, axis=1) * 1000.0
        disp = np.linalg.norm(v - source, axis=1) * 1000.0
        novelty = self.transfer.judged_novelty(out, prepared, sel.kind)
        strategy, label = (strategy, out.label) if example is None else ("example", example.name)
        return Prediction(strategy, label, v, err, disp, vertex_normals(v, prepared.faces), out.gate, out.signal,
                          novelty, out.detail, out.detail_mix, out.predictor, out.note), dt

    def slow_step(self, sel: Selection) -> str | None:
        """What makes computing `sel` slow the first time, for the status bar; None when nothing does."""
        if sel.example is not None or not self.is_mesh(sel.target) or sel.target not in self.targets:
            return None
        prepared = self.prepare(self.pair(sel.target, sel.kind, sel.pose))
        todo = self.transfer.registrations_to_fit(prepared, sel.kind, [sel.pose, sel.pose_b if sel.blend > 0 else None])
        return (f"fitting anny's template to {sel.target} stood in {', '.join(todo)} (another topology: the correctives "
                f"are read through it; about 20 s each, once)") if todo else None

    def compute(self, sel: Selection) -> ViewState:
        """Everything the views show for a selection (the one path: Transfer.prepare + predict)."""
        t0 = time.perf_counter()
        sel = self.validate(sel)
        example = None if sel.example is None else self.example(sel.example)
        pair = self.pair(sel.target, sel.kind, sel.pose)
        prepared = self.prepare(pair)
        source = prepared.vertices
        if example is not None:  # the rig has no state for the example's deformation of this target
            truth, truth_title = None, f"ground truth: none\n({example.label})"
        else:
            truth = self.truth_state(pair)
            truth_title = "ground truth: none\n(an opened mesh)" if truth is None else f"ground truth ({sel.pose})"
        if truth is not None and sel.pose_b is not None and sel.blend > 0:
            tb = self.truth_state(self.pair(sel.target, sel.kind, sel.pose_b))
            truth = ((1.0 - sel.blend) * truth + sel.blend * tb).astype(np.float32)
            truth_title = f"reference: truths blended\n{sel.pose} -> {sel.pose_b}\nat {sel.blend:.2f}, linearly"
        strategies = COMPARE_STRATEGIES if sel.compare and example is None else (sel.strategy,)
        preds, t_dec = [], 0.0
        for s in strategies:
            p, dt = self._predict(sel, s, prepared, source, truth, example)
            preds.append(p)
            t_dec += dt
        framing = frame(sel.focus, source, lambda: self._regions(prepared), [truth, preds[0].vertices],
                        None if example is not None else sel.pose)
        offset = None if example is None else example_offset(
            framing, example.neutral.vertices, example.posed.vertices, lambda: self._example_regions(example))
        opened = self.meshes.get(sel.target)
        return ViewState(sel, pair, prepared.faces, source, truth, truth_title, preds, time.perf_counter() - t0, t_dec,
                         example, framing, offset, "" if opened is None else opened.frame.describe())

    def _example_regions(self, example: ExamplePair) -> dict[str, np.ndarray] | None:
        """The head and hands of an example's A (its surface read once per pair: about a second)."""
        key = (example.name, example.stamp)
        if key not in self._example_masks:
            m = example.neutral
            self._example_masks[key] = self._regions(self.transfer.prepare_user_mesh(m))
        return self._example_masks[key]

    @staticmethod
    def _regions(prepared) -> dict[str, np.ndarray] | None:
        """The head and hands of a prepared mesh (its surface features, computed once per mesh), or None when its
        surface cannot be read as a humanoid's (the body is framed then)."""
        from latent_model.surface import detail_regions

        try:
            return detail_regions(prepared.surface.coords)
        except (ValueError, IndexError, RuntimeError):
            return None

    def export(self, state: ViewState, path: str | Path, which: int = 0) -> Path:
        """Write a prediction in the frame, units and vertex order of its source file."""
        return export_mesh(self.source_mesh(state.pair), state.predictions[which].vertices, path)

    # -------------------------------------------------------------- heatmaps
    def neutral_latents(self) -> tuple[list[str], np.ndarray]:
        """(training ids, (n, Z) neutral latent means) from the bank."""
        bank = self.transfer.bank
        rows = {k.split("/", 1)[0]: i for i, k in enumerate(bank.keys) if k.endswith("/neutral")}
        ids = [i for i in self.training_ids if i in rows]
        return ids, bank.mu[[rows[i] for i in ids]]

    def target_neutral_mu(self, target: str) -> np.ndarray:
        return self.prepared(target, "neutral_to_pose").mu

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
            v = self.truth.state(target, p, FINAL)
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

    # -------------------------------------------------------------- window state (UI thread)
    def select(self, sel: Selection) -> None:
        """Make `sel` the selection: the controls show it and the window asks for its prediction."""
        self.selection = sel
        self.events.selection.emit(sel)

    def condition(self, example: str | None) -> None:
        """Condition the current selection on a held example pair, or back on its pose (None)."""
        self.select(self.conditioned(self.selection or self.default_selection(), example))

    def restore(self, sel: Selection, meshes: dict[str, str],
                examples: dict[str, tuple[str, str]] | None = None) -> ToOpen:
        """A saved session: returns the meshes and the example pair that must be opened first (its
        selection is selected once they are, or at once when nothing is missing). The example pair
        is always opened again: unchanged files of a held pair are not re-encoded."""
        with self._meshes_lock:
            missing = {n: p for n, p in meshes.items() if n not in self.meshes}
        wanted = {} if sel.example is None else {n: tuple(p) for n, p in (examples or {}).items() if n == sel.example}
        if sel.example is not None and not wanted:  # a file that names the pair but not its files
            sel = replace(sel, example=None)
        if missing or wanted:
            self.pending_selection = sel
            self._pending_examples = {example_subject(*p): n for n, p in wanted.items()}
            self._pending_paths = set(missing.values()) | set(self._pending_examples)
        else:
            self.select(sel)
        return ToOpen(missing, wanted)

    def begin_noise(self, target: str) -> bool:
        """True when the noise floor of `target` must be computed now (it is then marked in
        flight); False when it is shown or already being computed."""
        if (self.noise is not None and self.noise.target == target) or self.noise_for == target:
            return False
        self.noise_for = target
        return True

    @singledispatchmethod
    def apply(self, result) -> None:
        """Take a worker's result into the window state and announce it (UI thread)."""
        raise TypeError(f"not a session result: {type(result).__name__}")

    @apply.register
    def _(self, result: Predicted) -> None:
        st = result.state
        self.state = st
        self.events.state.emit(st)
        req = HeatmapRequest(st.selection, st.conditioning)
        if req.key != self.heatmap_key:
            self.heatmap_key, self.heatmaps_pending = req.key, True
            self.events.heatmaps_wanted.emit(req)

    @apply.register
    def _(self, result: HeatmapData) -> None:
        if result.key != self.heatmap_key:
            return  # a job overtaken by a newer selection; the matching one is coming
        self.heatmap_data, self.heatmaps_pending = result, False
        self.events.heatmaps.emit(result)

    @apply.register
    def _(self, result: NoiseFloor) -> None:
        if self.noise_for is not None and result.target != self.noise_for:
            return  # overtaken: the noise floor of another target is being computed
        self.noise, self.noise_for = result, None
        self.events.noise.emit(result)

    @apply.register
    def _(self, result: MeshOpened) -> None:
        self.mesh_paths[result.name] = result.path
        self.events.mesh_opened.emit(result)
        self._pending_paths.discard(result.path)
        if self.pending_selection is not None:
            self._resolve_pending()
            return
        base = self.selection or self.default_selection()
        self.select(self._for_mesh(replace(base, target=result.name, kind=result.kind)))

    @apply.register
    def _(self, result: ExampleOpened) -> None:
        name = result.pair.name
        self.example_paths[name] = result.pair.paths
        self.events.example_opened.emit(result)
        saved = self._pending_examples.pop(result.subject, None)
        if self.pending_selection is not None:
            sel = self.pending_selection
            if saved is not None:  # a restored session's pair: the name it has now
                self.pending_selection = replace(sel, example=name) if sel.example == saved else sel
                self._pending_paths.discard(result.subject)
            else:  # the user's own pair, while a session is restored: it conditions the restored selection
                self.pending_selection = self.conditioned(sel, name)
            self._resolve_pending()
            return
        self.condition(name)

    @apply.register
    def _(self, result: Exported) -> None:
        self.events.exported.emit(result)

    @apply.register
    def _(self, result: Failed) -> None:
        if result.job is HeatmapData:
            self.heatmaps_pending, self.heatmap_key = False, None  # the next prediction asks again
        elif result.job is NoiseFloor:
            self.noise_for = None
        elif result.job is MeshOpened and self.pending_selection is not None:
            self._pending_paths.discard(result.subject)
            self._resolve_pending()
        elif result.job is ExampleOpened and result.subject in self._pending_examples:
            del self._pending_examples[result.subject]  # the restored selection goes back to its pose
            self._pending_paths.discard(result.subject)
            self._resolve_pending()
        self.events.failed.emit(result)

    def _resolve_pending(self) -> None:
        """Select the restored selection once none of its meshes is still opening."""
        if self._pending_paths:
            return
        sel, self.pending_selection = self.pending_selection, None
        if sel.target not in self.targets:  # its mesh failed to open: keep the current target
            sel = replace(sel, target=(self.selection or self.default_selection()).target)
        example = sel.example if sel.example in self.examples else None  # its pair failed: the pose conditions
        self.select(self.conditioned(self._for_mesh(sel), example))

    def _for_mesh(self, sel: Selection) -> Selection:
        """An opened mesh is the source of its pair kind (a neutral, a skinned pose...): poses that kind has."""
        if not self.is_mesh(sel.target):
            return sel
        poses = self.poses(sel.kind)
        return replace(sel, pose=sel.pose if sel.pose in poses else poses[0],
                       pose_b=sel.pose_b if sel.pose_b in poses else None)


@dataclass(frozen=True)
class Loaded:
    """The load job's result: the session, ready to predict."""

    session: Session
