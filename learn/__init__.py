"""PyTorch side of wrinkles: datasets, methods, losses, metrics, the trainer and the evaluation
harness. Imports ``sim`` (never ``pipelines``)."""
