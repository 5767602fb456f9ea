"""Experiment configurations shipped with the package (``mrm run table2`` reads table2.toml)."""
