"""One raw file -> one runs row and its samples Parquet: columns mapped onto standard names,
the time base, sensors, derived channels, the Parquet written."""
