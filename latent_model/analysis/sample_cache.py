"""SDF re-samplings of corpus states kept on disk between evaluations.

The noise-floor analyses re-sample ~340 states' geometry (`Corpus.resample_sdf`, 0.1-0.2 s each: about 50 s of
`lrr evaluate`); the re-samplings depend on the corpus alone, so the next evaluation of any model on the same
corpus reads them back. A file holds one (state row, re-sampling) pair (`np.savez`: points, values), named by the
corpus's config digest and a digest of the code that samples it, so another corpus or a changed sampler never
reads it.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from latent_model.analysis.latent_space import SampleCache
from latent_model.atomic import atomic_write
from latent_model.corpus.store import Corpus


class KeptSampleCache(SampleCache):
    """`SampleCache` whose re-samplings (r >= 1) are also kept as files in `directory`."""

    def __init__(self, corpus: Corpus, directory: str | Path) -> None:
        super().__init__(corpus)
        self.directory = Path(directory)

    def get(self, state: int, resample: int) -> tuple[np.ndarray, np.ndarray]:
        if resample == 0:
            return self.corpus.sdf(state)
        key = (self.corpus.row(state), resample)
        if key not in self._data:
            self._data[key] = self._kept(state, resample)
        return self._data[key]

    def path(self, state: int, resample: int) -> Path:
        """The file of state `state`'s re-sampling `resample`."""
        digest = self.corpus.manifest["config_digest"]
        return self.directory / f"{digest}_{resampling_code()}_r{resample}_s{self.corpus.row(state)}.npz"

    def _kept(self, state: int, resample: int) -> tuple[np.ndarray, np.ndarray]:
        path = self.path(state, resample)
        try:
            with np.load(path) as z:
                return z["points"], z["values"]
        except (OSError, KeyError, ValueError):
            pass  # not kept yet, or unreadable: sampled (again) and written
        points, values = self.corpus.resample_sdf(state, resample)
        atomic_write(path, lambda tmp: np.savez(tmp, points=points, values=values))
        return points, values


@lru_cache(maxsize=1)
def resampling_code() -> str:
    """A digest of the code a re-sampling runs (the SDF sampler and the seeds): changed code samples anew."""
    import hashlib
    import inspect

    from latent_model.corpus import sdf, store

    code = Path(sdf.__file__).read_bytes() + inspect.getsource(store.Corpus.resample_sdf).encode() + \
        inspect.getsource(store.sdf_seed).encode()
    return hashlib.sha256(code).hexdigest()[:12]
