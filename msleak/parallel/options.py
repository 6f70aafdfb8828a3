"""The ``--scheduler`` and ``--workers`` options of ``msleak predict`` and ``msleak grid``."""

from __future__ import annotations

import click

from msleak.errors import InputError
from msleak.parallel.runner import check_scheduler

__all__ = ["parallel_options"]

SCHEDULER_HELP = ("Where chunks run: threads (default; all cores), processes, sync (serial, "
                  "one chunk at a time), or the address of a dask.distributed scheduler, e.g. "
                  "tcp://host:8786 (docs/parallel.md).")
WORKERS_HELP = ("Chunks computed at the same time [default: all cores; with a scheduler "
                "address, every worker thread of the cluster].")


def _scheduler(_ctx, _param, value):
    try:
        return check_scheduler(value)
    except InputError as err:
        raise click.BadParameter(str(err)) from None


def parallel_options(func):
    """Add ``--scheduler`` and ``--workers`` to a click command."""
    func = click.option("--workers", type=click.IntRange(min=1, max=1024), default=None,
                        metavar="N", help=WORKERS_HELP)(func)
    func = click.option("--scheduler", default="threads", show_default=True,
                        metavar="threads|processes|sync|ADDRESS", callback=_scheduler,
                        help=SCHEDULER_HELP)(func)
    return func
