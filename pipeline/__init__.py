"""pneubench pipeline: readers, ingest, rebuild orchestration, simulator and the CLI."""
__version__ = "0.1.0"
