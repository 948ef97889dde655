"""The Hydra configs, shipped as package data (found by tasks.catalog.conf_dir)."""
