"""Characters of an evaluation shared among processes (latent_model/analysis/parallel.py): results come back in the
items' order, and each worker runs one thread for torch and one for numpy's BLAS (two processes each spinning two
OpenBLAS threads on two cores ran an analysis 1.2x faster than one process instead of 2x)."""
import pytest

from latent_model.analysis.parallel import map_characters, resolve_workers


def _threads(transfer, corpus, shared, item):  # module level: a worker receives it by name
    import torch
    from threadpoolctl import threadpool_info

    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    return item, shared, torch.get_num_threads(), max(blas, default=1)


def test_workers_return_in_order_and_run_one_thread_each():
    out = map_characters(_threads, range(5), None, workers=2, shared="shared")
    assert [o[:2] for o in out] == [(k, "shared") for k in range(5)]
    assert all(torch_threads == 1 and blas_threads == 1 for _, _, torch_threads, blas_threads in out)


def test_worker_counts():
    assert resolve_workers(None, 1) == 1 and resolve_workers(3, 10) == 3
    with pytest.raises(ValueError, match="--workers 0"):
        resolve_workers(0, 4)
