"""The Hydra configs, shipped as package data (found by tasks.factory.conf_dir)."""
