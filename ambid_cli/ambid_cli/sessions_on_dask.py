"""Sessions as tasks on Dask distributed: what ``ambid validate`` and ``ambid campaign`` run them on.

A LocalCluster of one single-threaded worker process per session at once
(this machine's cores by default), or the cluster whose scheduler
``--scheduler ADDRESS`` names. Each session runs alone in its worker process
on its own ROS domain (``ROS_DOMAIN_ID``: a base the command chooses plus the
worker's number; on a cluster, name each host's workers 0, 1, ... with
``dask worker --name``), so two sessions never hear each other. Results come
back as they finish; a failed task is reported, never a reason to lose the
others.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["DOMAIN_SLOTS", "add_scheduler_option", "domain_base", "session_client", "run_in_domain", "as_finished"]

#: ROS domain ids one command's sessions may take, from its base (one per worker at once)
DOMAIN_SLOTS = 8


def add_scheduler_option(p) -> None:
    """``--scheduler ADDRESS``, ``--jobs N`` and ``--domain-base ID`` on an argparse parser."""
    from ambid_cli.commands.inputs import positive_int

    p.add_argument("--scheduler", default="", metavar="ADDRESS",
                   help="a Dask scheduler to run the sessions on (e.g. tcp://host:8786); default a local cluster of "
                        "this machine's cores")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="sessions at once on the local cluster (default: the cores)")
    p.add_argument("--domain-base", type=int, default=None, metavar="ID",
                   help=f"first ROS domain id of the sessions (they take ID .. ID + {DOMAIN_SLOTS - 1}; default 215 "
                        "or 223, from this process): keep it clear of other users of this machine")


def domain_base(args) -> int:
    """The first ROS domain id of a command's sessions: ``--domain-base``, else 215 or 223 (from the process id),
    outside the 100-199 that identify and graph derive from their pid, so a session on this machine does not
    hear (and reject) ours."""
    return args.domain_base if args.domain_base is not None else 215 + (os.getpid() % 2) * DOMAIN_SLOTS


@contextmanager
def session_client(scheduler: str = "", jobs: int | None = None, n_tasks: int = 1) -> Iterator[Any]:
    """A dask.distributed Client: to ``scheduler`` if given, else to a LocalCluster of ``jobs`` (default the
    cores, at most ``n_tasks``, at most :data:`DOMAIN_SLOTS`) single-threaded worker processes."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout="30s") as client:
            yield client
        return
    n = max(1, min(jobs or os.cpu_count() or 1, n_tasks, DOMAIN_SLOTS))
    # one thread per worker process: a session owns its process (its rclpy context, its numba and BLAS threads)
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=40) as cluster, Client(cluster) as client:
        yield client


def _worker_slot() -> int:
    from dask.distributed import get_worker

    name = get_worker().name
    try:
        return int(name) % DOMAIN_SLOTS
    except (TypeError, ValueError):
        return zlib.crc32(str(name).encode()) % DOMAIN_SLOTS


def run_in_domain(domain_base: int, fn: Callable, *args, **kwargs):
    """Run ``fn(*args, **kwargs)`` in this worker with ROS_DOMAIN_ID = domain_base + the worker's slot (a Dask
    task; the session's nodes read the variable when they start)."""
    os.environ["ROS_DOMAIN_ID"] = str(domain_base + _worker_slot())
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return fn(*args, **kwargs)


def as_finished(client, domain_base: int, fn: Callable, items: Iterable[tuple[Any, tuple]]
                ) -> Iterator[tuple[Any, Any, BaseException | None]]:
    """Submit ``fn(*args)`` for each (key, args) of ``items`` as one task each; yield (key, result, None) or
    (key, None, error) as the tasks finish."""
    from dask.distributed import as_completed

    futures = {}
    for key, args in items:
        fut = client.submit(run_in_domain, domain_base, fn, *args, pure=False, key=f"ambid-{key}-{os.getpid()}")
        futures[fut] = key
    for fut in as_completed(list(futures)):
        key = futures[fut]
        try:
            yield key, fut.result(), None
        except Exception as exc:  # one failed session must not lose the others
            yield key, None, exc
