"""Whole runs and benches of the policies on simulated rigs, as ``optalign run --sim`` and
``optalign bench`` do them."""

from __future__ import annotations

import json
import os
from typing import Iterable, Optional, Union

from . import _native

PathLike = Union[str, "os.PathLike[str]"]


def _path(path: Optional[PathLike]) -> Optional[str]:
    return None if path is None else os.fspath(path)


def run(
    task: str,
    policy: str = "vision",
    seed: int = 0,
    scenario: Optional[PathLike] = None,
    motors: str = "in-process",
    out: Optional[PathLike] = None,
) -> dict:
    """Runs one episode of ``task`` ("michelson", "cavity" or "relay") with ``policy``
    ("vision", "bo", "random", or "manual" at a prompt on standard input) on the simulated rig of ``seed`` and returns the run
    summary (success, terminal and best error, evaluations, error traces, modelled time).

    ``scenario`` is a scenario TOML file (defaults when omitted); ``motors`` is
    "in-process" or "peer" (the simulated firmware over loopback TCP). With ``out`` the
    transcript, frames and summary are written to that folder.
    """
    return json.loads(
        _native.run_json(task, policy, seed, _path(scenario), motors, _path(out))
    )


def bench(
    tasks: Iterable[str] = ("michelson", "cavity", "relay"),
    policies: Iterable[str] = ("vision",),
    seeds: Iterable[int] = range(10),
    scenario: Optional[PathLike] = None,
    motors: str = "in-process",
    jobs: Optional[int] = None,
) -> list:
    """Runs the task x policy x seed matrix in parallel (``jobs`` threads, one per core by
    default) and returns one dict per run with the columns of ``results.csv``, ready for
    ``pandas.DataFrame(rows)``."""
    if isinstance(tasks, str) or isinstance(policies, str):
        raise TypeError("tasks and policies are lists of names, e.g. ['cavity']")
    table = json.loads(
        _native.bench_json(
            list(tasks), list(policies), [int(s) for s in seeds], _path(scenario), motors, jobs
        )
    )
    return [dict(zip(table["columns"], values)) for values in table["rows"]]
