"""On-disk corpus: a JSON manifest plus memory-mappable .npy arrays.

Layout of a corpus directory::

    manifest.json     format version, config + digest, identities, poses, completeness
    states.npy        (S, 4) int32: identity, pose index (-1 = neutral), variant index, geometry row
    faces.npy         (F, 3) int32 full mesh;  body_faces.npy: the body shell used for SDF
    mirror_map.npy    (V,) left/right vertex partner
    vertices.npy      (G, V, 3) float32
    normals.npy       (G, V, 3) float16 (unit normals; half precision keeps the standard
                      corpus within its disk budget, read back as float32)
    sdf_points.npy    (G, K, 3) float32;  sdf_values.npy (G, K) float32
    progress.json     (while building) identities finished so far

Several states may share one geometry row (a face-only pose's `skinning` state is the neutral
geometry). Every identity owns a contiguous block of rows, so workers write disjoint blocks
and a killed build resumes by redoing only unfinished identities. JSON files are written
atomically (temp file + rename); a build lives in ``DIR.partial`` until complete.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from latent_model.atomic import atomic_write
from latent_model.corpus.config import CorpusConfig
from latent_model.errors import UserFacingError
from latent_model.types import FINAL, PRESETS, VARIANTS
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import get_pose


FORMAT_VERSION = 1
KIND = "lrr-corpus"
ARRAYS = ("vertices", "normals", "sdf_points", "sdf_values")


class CorpusError(UserFacingError, RuntimeError):
    """A corpus that is missing, incomplete, of another format or corrupt (message says the fix)."""


def atomic_save_npy(path: Path, array: np.ndarray) -> None:
    atomic_write(path, lambda tmp: np.save(tmp, array))


@dataclass(frozen=True)
class Layout:
    """Geometry-row layout: which rows each identity owns and which states point where."""

    n_identities: int
    poses: tuple[str, ...]

    @cached_property
    def block(self) -> int:
        """Geometry rows per identity: neutral + 3 per skeletal pose + 1 per face-only pose."""
        return 1 + sum(3 if get_pose(p).has_skeletal else 1 for p in self.poses)

    @property
    def n_geometries(self) -> int:
        return self.n_identities * self.block

    def identity_rows(self, i: int) -> range:
        return range(i * self.block, (i + 1) * self.block)

    def local_states(self) -> list[tuple[int, int, int]]:
        """(pose index or -1, variant index, row offset within the identity block) for every state."""
        v = {name: k for k, name in enumerate(VARIANTS)}
        out = [(-1, v["neutral"], 0)]
        row = 1
        for pi, name in enumerate(self.poses):
            if get_pose(name).has_skeletal:
                for variant in VARIANTS[1:]:  # the posed variants
                    out.append((pi, v[variant], row))
                    row += 1
            else:  # face only: skinning == neutral, skinning_plus_blendshape == blendshape
                out.append((pi, v["skinning"], 0))
                out.append((pi, v["blendshape"], row))
                out.append((pi, v[FINAL], row))
                row += 1
        return out

    def state_table(self) -> np.ndarray:
        """(S, 4) int32: identity, pose index (-1 neutral), variant index, geometry row."""
        local = self.local_states()
        rows = [(i, p, v, i * self.block + r) for i in range(self.n_identities) for p, v, r in local]
        return np.asarray(rows, dtype=np.int32)


class RowFile:
    """Reads single rows of a .npy array with `os.pread` (no memory map), so scanning a corpus bigger than
    memory leaves the page cache to the kernel instead of growing the process's resident set (a memory
    map keeps every page it touched: 5 GB after one pass over corpus v4's vertices). Opened lazily per
    process (a Corpus may be used after a fork)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            shape, fortran, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                     else np.lib.format.read_array_header_2_0(f))
            self.offset = f.tell()
        if fortran:
            raise CorpusError(f"{path} is stored in Fortran order; rebuild the corpus")
        self.shape, self.dtype = tuple(shape), np.dtype(dtype)
        self.row_bytes = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        self._fd: tuple[int, int] | None = None  # (pid, fd)

    def row(self, r: int) -> np.ndarray:
        if self._fd is None or self._fd[0] != os.getpid():
            self._fd = (os.getpid(), os.open(self.path, os.O_RDONLY))
        buf = os.pread(self._fd[1], self.row_bytes, self.offset + int(r) * self.row_bytes)
        if len(buf) != self.row_bytes:
            raise CorpusError(f"{self.path} is truncated at row {r}; rebuild the corpus with `lrr corpus build --force`")
        return np.frombuffer(buf, dtype=self.dtype).reshape(self.shape[1:]).copy()

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_fd": None}

    def __del__(self) -> None:  # os imported at module level: a lazy import fails at interpreter exit
        if self._fd is not None and self._fd[0] == os.getpid():
            os.close(self._fd[1])


def _open_arrays(directory: Path, mode: str) -> dict[str, np.ndarray]:
    return {name: np.load(directory / f"{name}.npy", mmap_mode=mode) for name in ARRAYS}


def create_arrays(directory: Path, n_geometries: int, n_vertices: int, k: int) -> None:
    """Allocate the big arrays (sparse files) if absent."""
    shapes = {
        "vertices": ((n_geometries, n_vertices, 3), np.float32),
        "normals": ((n_geometries, n_vertices, 3), np.float16),
        "sdf_points": ((n_geometries, k, 3), np.float32),
        "sdf_values": ((n_geometries, k), np.float32),
    }
    for name, (shape, dtype) in shapes.items():
        path = directory / f"{name}.npy"
        if path.exists():
            a = np.load(path, mmap_mode="r")
            if a.shape != shape or a.dtype != dtype:
                raise CorpusError(f"{path} has shape {a.shape} {a.dtype}, expected {shape} {dtype}; "
                                  f"delete {directory} and rebuild")
            continue
        np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=shape).flush()


def write_block(directory: Path, rows: range, vertices: np.ndarray, normals: np.ndarray,
                sdf_points: np.ndarray, sdf_values: np.ndarray) -> None:
    """Write one identity's rows into the memory-mapped arrays and flush them to disk."""
    arrays = _open_arrays(directory, "r+")
    sl = slice(rows.start, rows.stop)
    arrays["vertices"][sl] = vertices
    arrays["normals"][sl] = normals.astype(np.float16)
    arrays["sdf_points"][sl] = sdf_points
    arrays["sdf_values"][sl] = sdf_values
    for a in arrays.values():
        a.flush()


class Corpus:
    """Read access to a finished corpus directory (arrays memory-mapped, nothing loaded eagerly)."""

    def __init__(self, path: str | Path, allow_partial: bool = False) -> None:
        self.path = Path(path)
        m = self.path / "manifest.json"
        if not m.exists():
            partial = Path(str(self.path) + ".partial")
            if partial.exists():
                raise CorpusError(f"the corpus build at {partial} is unfinished; resume it by running the "
                                  f"same `lrr corpus build` command again")
            preset = self.path.name if self.path.name in PRESETS else "|".join(PRESETS)
            raise CorpusError(f"no corpus at {self.path} (missing manifest.json); build one with "
                              f"`lrr corpus build --preset {preset} --out {self.path}`")
        try:
            self.manifest = json.loads(m.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise CorpusError(f"{m} is unreadable ({e}); delete {self.path} and rebuild with `lrr corpus build`") from e
        if self.manifest.get("kind") != KIND:
            raise CorpusError(f"{self.path} is not a LatentReRig corpus")
        fv = self.manifest.get("format_version")
        if fv != FORMAT_VERSION:
            raise CorpusError(f"{self.path} has corpus format version {fv}, this program reads version "
                              f"{FORMAT_VERSION}; rebuild it with `lrr corpus build --force`")
        if not self.manifest.get("complete") and not allow_partial:
            done = len(self.manifest.get("done_identities", []))
            raise CorpusError(f"{self.path} is a partial corpus ({done} of {self.manifest['n_identities']} identities"
                              f"{', shard ' + self.manifest['shard'] if self.manifest.get('shard') else ''}); "
                              f"finish or merge it (`lrr corpus merge`) before use")
        self.config = CorpusConfig.from_dict(self.manifest["config"])
        self.poses: tuple[str, ...] = tuple(self.manifest["poses"])
        self.identities = [IdentitySpec.from_dict(d) for d in self.manifest["identities"]]
        self.identity_stats: list[dict] = self.manifest.get("identity_stats", [])
        try:
            self.states = np.load(self.path / "states.npy")
            self.faces = np.load(self.path / "faces.npy").astype(np.int64)
            self.body_faces = np.load(self.path / "body_faces.npy").astype(np.int64)
            self.mirror_map = np.load(self.path / "mirror_map.npy").astype(np.int64)
            self._arrays = _open_arrays(self.path, "r")
            self._rows = {name: RowFile(self.path / f"{name}.npy") for name in ARRAYS}
        except (OSError, ValueError) as e:
            raise CorpusError(f"{self.path} is corrupt ({e}); delete it and rebuild with `lrr corpus build --force`") from e
        G = self.manifest["n_geometries"]
        for name, a in self._arrays.items():
            if a.shape[0] != G:
                raise CorpusError(f"{self.path}/{name}.npy has {a.shape[0]} rows, manifest says {G}; "
                                  f"the corpus is corrupt: rebuild with `lrr corpus build --force`")
        self._index = {(int(i), int(p), int(v)): s for s, (i, p, v, _) in enumerate(self.states)}

    # ------------------------------------------------------------------ look-ups
    @property
    def n_vertices(self) -> int:
        return int(self.manifest["n_vertices"])

    def identity_index(self, identity: str | int) -> int:
        if isinstance(identity, (int, np.integer)):
            if not 0 <= identity < len(self.identities):
                raise KeyError(f"identity index {identity} out of range 0..{len(self.identities) - 1}")
            return int(identity)
        for i, s in enumerate(self.identities):
            if s.id == identity:
                return i
        raise KeyError(f"unknown identity {identity!r}; valid: {', '.join(s.id for s in self.identities)}")

    def pose_index(self, pose: str | None) -> int:
        if pose is None or pose == "neutral":
            return -1
        if pose not in self.poses:
            get_pose(pose)  # unknown everywhere -> lists the vocabulary
            raise KeyError(f"pose {pose!r} is not in this corpus; its poses: {', '.join(self.poses)}")
        return self.poses.index(pose)

    def state(self, identity: str | int, pose: str | None, variant: str) -> int:
        """State index of (identity, pose or None for neutral, variant)."""
        if variant not in VARIANTS:
            raise KeyError(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
        key = (self.identity_index(identity), self.pose_index(pose), VARIANTS.index(variant))
        if key not in self._index:
            raise KeyError(f"no state {identity}/{pose}/{variant}; the neutral state has variant 'neutral' and no pose")
        return self._index[key]

    def parse_state(self, text: str) -> int:
        """'id003/elbowBentLf/skinning' or 'id003/neutral' -> state index."""
        parts = text.split("/")
        if len(parts) == 2 and parts[1] == "neutral":
            return self.state(parts[0], None, "neutral")
        if len(parts) != 3:
            raise KeyError(f"state {text!r} must look like ID/POSE/VARIANT or ID/neutral, e.g. "
                           f"{self.identities[0].id}/{self.poses[0]}/skinning_plus_blendshape")
        return self.state(parts[0], parts[1], parts[2])

    def state_name(self, s: int) -> str:
        i, p, v, _ = self.states[s]
        ident = self.identities[i].id
        return f"{ident}/neutral" if p < 0 else f"{ident}/{self.poses[p]}/{VARIANTS[v]}"

    def row(self, s: int) -> int:
        return int(self.states[s, 3])

    def split_indices(self, split: str, rest: str | None = None) -> list[int]:
        """Identities (characters) of a split ("train" | "val" | "test"), optionally of one rest."""
        return [i for i, s in enumerate(self.identities) if s.split == split and (rest is None or s.rest == rest)]

    def person_classes(self, split: str = "train") -> dict[int, int]:
        """Character index -> its person's class (0..P-1, in person order): a person's rests share one."""
        persons = list(dict.fromkeys(self.identities[i].person_id for i in self.split_indices(split)))
        return {i: persons.index(self.identities[i].person_id) for i in self.split_indices(split)}

    @property
    def rests(self) -> tuple[str, ...]:
        """The rest configurations its characters stand in (bind first)."""
        return tuple(dict.fromkeys(s.rest for s in self.identities))

    # ------------------------------------------------------------------ arrays
    def vertices(self, s: int) -> np.ndarray:
        """(V, 3) float32."""
        return self._rows["vertices"].row(self.row(s))

    def normals(self, s: int) -> np.ndarray:
        """(V, 3) float32."""
        return self._rows["normals"].row(self.row(s)).astype(np.float32)

    def sdf(self, s: int) -> tuple[np.ndarray, np.ndarray]:
        """Stored SDF samples: points (K, 3), values (K,)."""
        return self.sdf_of_row(self.row(s))

    def sdf_of_row(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Stored SDF samples of geometry row r: points (K, 3), values (K,)."""
        return self._rows["sdf_points"].row(r), self._rows["sdf_values"].row(r)

    def resample_sdf(self, s: int, resample: int, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """An independent seeded re-sampling of state `s`'s geometry (resample >= 1; 0 = stored)."""
        from dataclasses import replace

        from latent_model.corpus.sdf import sample_sdf

        cfg = self.config.sdf if k is None else replace(self.config.sdf, k=k)
        if resample == 0 and k is None:
            return self.sdf(s)
        return sample_sdf(self.vertices(s).astype(np.float64), self.body_faces, cfg,
                          sdf_seed(self.config.seed, self.row(s), resample))

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        return self._arrays


def sdf_seed(corpus_seed: int, row: int, resample: int = 0) -> int:
    """Seed of the SDF sampling of one geometry row (resample 0 is the stored one)."""
    return int(np.random.SeedSequence([corpus_seed, row, resample]).generate_state(1)[0])
