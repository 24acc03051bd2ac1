"""``rovslam batch``: a robustness matrix of dives run on Dask (a local cluster, or an existing one).

Each cell (scenario x seed, or a recorded sequence with ground truth) is one Dask task that
simulates, runs, evaluates and computes the baselines (:mod:`rovslam.batch.cell`). Finished
cells are kept and skipped when the batch is run again; a failing cell is reported in the
tables, never fatal to the others. Only the CLI imports this package.

On an existing cluster (``scheduler=ADDRESS``) the workers need rovslam installed and the
output folder (and any sequence folders of the matrix) on a file system they share.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rovslam.batch.cell import pending_row, read_result, run_cell
from rovslam.batch.matrix import CellSpec, Matrix, load_matrix
from rovslam.batch.table import MATRIX_COLUMNS, SUMMARY_FIGURES, GroupSummary, summarise, write_tables

__all__ = [
    "BatchReport",
    "CellSpec",
    "GroupSummary",
    "MATRIX_COLUMNS",
    "Matrix",
    "SUMMARY_FIGURES",
    "default_workers",
    "load_matrix",
    "run_cell",
    "run_matrix",
    "summarise",
    "worker_environ",
    "write_tables",
]


@dataclass
class BatchReport:
    """What :func:`run_matrix` did: every cell's row in matrix order, which cells ran now and which were kept.

    A row's ``status`` is ``ok``, ``failed`` or, for a cell an interrupted batch did not finish, ``pending``.
    """

    rows: list[dict[str, Any]]
    computed: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    interrupted: bool = False

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r.get("status") == "failed"]

    @property
    def exit_code(self) -> int:
        """0: no cell failed; 2: cells failed, every one for bad input (its one line in the table); 1: a cell hit a bug."""
        failed = self.failed
        if not failed:
            return 0
        return 2 if all(r.get("failure") == "input" for r in failed) else 1


def default_workers() -> int:
    """One worker per core this process may use."""
    from rovslam.process import usable_cores

    return usable_cores()


def worker_environ() -> dict:
    """Dask's environment for new worker processes, less ``MALLOC_TRIM_THRESHOLD_``.

    Dask sets it to 64 KiB, which also turns off glibc's adaptive mmap threshold: every large
    NumPy array is then mapped and unmapped afresh, and the simulator and the pipeline spend
    2 to 3 times the CPU (measured: 8.7 s instead of 3.2 s for a 60-frame portofino dive).
    """
    import dask
    import distributed  # noqa: F401  (registers its configuration defaults)

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    env.pop("MALLOC_TRIM_THRESHOLD_", None)
    return env


def run_matrix(
    matrix: Matrix,
    out_dir: str | Path,
    scheduler: str | None = None,
    workers: int | None = None,
    keep_sequences: bool = False,
    on_start: Callable[[int, int], None] | None = None,
    on_cell: Callable[[dict[str, Any]], None] | None = None,
) -> BatchReport:
    """Run every cell of ``matrix`` not yet done in ``out_dir`` and write ``matrix.csv`` / ``matrix.md``.

    ``scheduler``: the address of an existing Dask scheduler; default a local cluster of
    ``workers`` processes (default :func:`default_workers`), one thread each.
    ``on_start(done, total)`` is called once the finished cells are known; ``on_cell(row)``
    for every cell computed now, as it completes. The
    tables are rewritten after every cell, so an interrupted batch (Ctrl-C) leaves tables of
    what is done; ``BatchReport.interrupted`` then says so.
    """
    from rovslam.io.output import check_output_folder

    out = check_output_folder(out_dir, "--out")  # a file, a device, a FIFO: refused before anything runs
    cells_dir = out / "cells"
    rows: dict[str, dict[str, Any]] = {}
    report = BatchReport(rows=[])
    for spec in matrix.cells:
        row = read_result(cells_dir / spec.cell_id)
        if row is not None:
            rows[spec.cell_id] = row
            report.reused.append(spec.cell_id)
    todo = [c for c in matrix.cells if c.cell_id not in rows]

    def ordered() -> list[dict[str, Any]]:  # every cell, those not run (yet) as "pending"
        return [rows[c.cell_id] if c.cell_id in rows else pending_row(c) for c in matrix.cells]

    def save() -> None:
        write_tables(out, matrix.name, ordered(), matrix.groups)

    client = cluster = None
    try:
        if todo:  # first, so that a wrong --scheduler fails alone, before anything is written
            client, cluster = _connect(scheduler, workers)
        cells_dir.mkdir(parents=True, exist_ok=True)
        if on_start is not None:
            on_start(len(rows), len(matrix.cells))
        save()
        if todo:
            _run_cells(client, todo, cells_dir, keep_sequences, rows, report, on_cell, save)
    except KeyboardInterrupt:
        report.interrupted = True
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    for spec in todo:  # a cell a worker finished (result.json written) that the interrupt kept us from gathering
        row = read_result(cells_dir / spec.cell_id) if spec.cell_id not in rows else None
        if row is not None:
            rows[spec.cell_id] = row
            report.computed.append(spec.cell_id)
    report.rows = ordered()
    if out.is_dir():
        save()
    return report


def _connect(scheduler: str | None, workers: int | None):
    """A Dask client of the scheduler at ``scheduler``, or of a new local cluster: ``(client, cluster or None)``."""
    import logging

    import dask
    from dask.distributed import Client, LocalCluster

    from rovslam.errors import ClusterError

    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise ClusterError(
                f"--scheduler {scheduler}: no Dask scheduler answered ({type(exc).__name__}: {exc}); "
                "give the address `dask scheduler` prints, e.g. tcp://10.0.0.5:8786"
            ) from None
    # dashboard_address ":0": any free port (None means Dask's 8787: with another cluster on the machine,
    # Dask warned about it on stderr, around rovslam's own lines).
    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environ()}):
        cluster = LocalCluster(
            n_workers=workers or default_workers(),
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.ERROR,
        )
    return Client(cluster), cluster


def _run_cells(client, todo, cells_dir, keep_sequences, rows, report, on_cell, save) -> None:
    import uuid

    from dask.distributed import as_completed

    from rovslam.batch.cell import ERROR_FILE, failed_row
    from rovslam.errors import RovslamError
    from rovslam.io.output import atomic_write_text

    futures = {}
    batch_id = uuid.uuid4().hex[:8]  # two batches on one scheduler never share a task
    for spec in todo:
        # Longest cells first, so the last ones to finish are short; pure=False: a re-run recomputes.
        fut = client.submit(
            run_cell,
            spec,
            str(cells_dir),
            keep_sequences,
            key=f"rovslam-cell-{spec.cell_id}-{batch_id}",
            pure=False,
            priority=spec.frames or 0,
        )
        futures[fut] = spec
    for fut in as_completed(futures):
        spec = futures[fut]
        try:
            row = fut.result()
        except Exception as exc:  # the worker died (out of memory, killed): a failed cell, not a failed batch
            row = failed_row(spec, exc)
            log = cells_dir / spec.cell_id / ERROR_FILE
            try:
                log.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_text(log, f"the Dask task of this cell failed: {exc!r}\n", "the cell's error.log")
            except (OSError, RovslamError):
                pass
        rows[spec.cell_id] = row
        report.computed.append(spec.cell_id)
        save()
        if on_cell is not None:
            on_cell(row)
