"""Process tuning: glibc keeps freed memory for reuse (the decoder's temporaries); OpenMP spin default."""
import os
import sys

import pytest

from latent_model.runtime import keep_freed_memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_keep_freed_memory_takes_effect_on_glibc():
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("not glibc")
    assert keep_freed_memory() is True


def test_short_thread_spin_sets_a_default_and_respects_the_user(monkeypatch):
    """The explorer's OpenMP setting: a short spin by default; a user's wait policy or spin count wins."""
    from latent_model.runtime import SPIN_COUNT, short_thread_spin

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    short_thread_spin()
    assert os.environ["GOMP_SPINCOUNT"] == str(SPIN_COUNT)
    monkeypatch.setenv("GOMP_SPINCOUNT", "5")
    short_thread_spin()
    assert os.environ["GOMP_SPINCOUNT"] == "5"
    monkeypatch.delenv("GOMP_SPINCOUNT")
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    short_thread_spin()
    assert "GOMP_SPINCOUNT" not in os.environ
