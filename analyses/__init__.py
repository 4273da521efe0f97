"""Analyses: pure functions from tables (pandas DataFrames in SI) to result tables and figures.

Nothing here knows about the warehouse, the CLI or the file system; every function can be
called from a notebook on a DataFrame from ``pneubench query`` or from the simulator.
"""
