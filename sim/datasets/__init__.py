"""Synthetic garment datasets: storage, the sequence schema, config, sampling, derived data."""
