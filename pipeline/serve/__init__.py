"""The read-only side: the door to the warehouse (``door``), one checked SQL statement
(``query``), its output formats (``formats``), the catalogue of tables, one run's plot and the
figures (``plots``), the docs' table reference (``reference``), the morning report and the run
pages."""
