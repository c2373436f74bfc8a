"""The shared training loop (``trainer``), its configs, checkpoints, EMA, logs and DDP helpers."""
