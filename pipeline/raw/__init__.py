"""What is in ``raw/``: the tree walk, the files that are runs, and every run's metadata
(rig.toml, manifest.csv, embedded metadata, parts) decided in one place. Nothing here writes."""
