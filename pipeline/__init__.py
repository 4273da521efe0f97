"""pneubench pipeline: readers, ingest, rebuild orchestration, simulator and the CLI."""
import os as _os

__version__ = "0.1.0"

# One BLAS thread per process, set before numpy is imported (OpenBLAS reads it when it loads; a value
# the user set is kept). A rebuild already runs one worker per core, and OpenBLAS's threads spin while
# they wait: under load a pressure group's fit (12,000 samples, ~20 small products) burned 0.5-0.7 CPU-s
# in them against 0.04 with one thread, the same bits (issue 26, "Session 25, spring").
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
