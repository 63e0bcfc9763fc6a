"""Characters of an evaluation shared among processes (latent_model/analysis/parallel.py): results come back in the
items' order, and each worker runs one thread for torch and one for numpy's BLAS (two processes each spinning two
OpenBLAS threads on two cores ran an analysis 1.2x faster than one process instead of 2x)."""
import os

import pytest

from latent_model.analysis.parallel import Workers, resolve_workers


def _threads(transfer, corpus, shared, item):  # module level: a worker receives it by name
    import torch
    from threadpoolctl import threadpool_info

    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    return item, shared, torch.get_num_threads(), max(blas, default=1)


def test_workers_return_in_order_and_run_one_thread_each():
    with Workers(None, None, 2) as pool:
        out = pool.map(_threads, range(5), shared="shared")
    assert [o[:2] for o in out] == [(k, "shared") for k in range(5)]
    assert all(torch_threads == 1 and blas_threads == 1 for _, _, torch_threads, blas_threads in out)


def _pid(transfer, corpus, shared, item):
    import os

    return item, shared, os.getpid()


def test_one_set_of_processes_runs_queued_analyses_with_their_own_inputs():
    """Two analyses queued on one `Workers` before either is read: each item gets its own analysis's shared
    input, the results come back in order (through each batch's summary), and both ran on the same processes."""
    with Workers(None, None, 2) as pool:
        first = pool.submit(_pid, range(4), shared="first")
        second = pool.submit(_pid, range(3), shared={"second": 2}, then=lambda out: out[::-1])
        b, a = second.get(), first.get()
    assert [x[:2] for x in a] == [(k, "first") for k in range(4)]
    assert [x[:2] for x in b] == [(k, {"second": 2}) for k in (2, 1, 0)]
    pids = {x[2] for x in a + b}
    assert len(pids) <= 2 and os.getpid() not in pids


def test_one_process_computes_when_read():
    """workers=1: no process is started; a batch is computed by its get() in this process."""
    with Workers(None, None, 1) as pool:
        batch = pool.submit(_pid, range(2), shared="s")
        assert [x[:2] for x in batch.get()] == [(0, "s"), (1, "s")]
        assert all(x[2] == os.getpid() for x in pool.map(_pid, range(2)))


def test_worker_counts():
    assert resolve_workers(None, 1) == 1 and resolve_workers(3, 10) == 3
    with pytest.raises(ValueError, match="--workers 0"):
        resolve_workers(0, 4)
