"""The read-only side: the SQL door (``query``), its output formats, the morning report and
the run pages."""
