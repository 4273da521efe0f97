"""Analysis stages of the rebuild: the glue between the warehouse and the pure ``analyses``.

Each module in this package that defines ``NAME`` and ``run`` is one stage; it declares what it
reads and writes (:mod:`pipeline.stages.registry`)::

    NAME = "plpa_characterisation"                  # unique, used in logs and figure paths
    READS = Reads(kinds=("leakage", "breakaway"))   # run kinds, earlier stages' tables, logbooks
    WRITES = ("leakage_map", ...)                   # warehouse tables it fills (DDL in schemas/ddl/)

    def run(ctx: StageContext) -> StageOutput: ...

The rebuild runs a stage after the stages that write what it reads, re-runs it only when what
it declared changed, and gives it a context holding only that (:mod:`pipeline.stages.context`).
A stage calls functions of ``analyses/`` (which know nothing of the warehouse) and returns
DataFrames per table, figures, quarantine rows and per-run warnings. A run that cannot be
analysed gives NULLs and a warning, never an exception; an exception out of ``run`` fails the
rebuild (the previous warehouse stays). The rebuild then adds the columns of
:mod:`pipeline.stages.run_columns` to every table.

This module names what other code uses of the stage framework.
"""
from pipeline.stages.context import (Carrying, DeclaredContext, FigureRecipe, StageContext, StageOutput, UndeclaredRead,
                                     figure_of, read_samples)
from pipeline.stages.registry import Reads, StageCircle, discover, reads_of, run_order, writes_of
from pipeline.stages.run_columns import add_run_columns

__all__ = ["Carrying", "DeclaredContext", "FigureRecipe", "Reads", "StageCircle", "StageContext", "StageOutput", "UndeclaredRead",
           "add_run_columns", "discover", "figure_of", "read_samples", "reads_of", "run_order", "writes_of"]
