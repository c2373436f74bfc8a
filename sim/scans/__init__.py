"""Scans of simulated garments: what a ring of depth cameras sees of a garment on a body
(``scanner``), the scan-like input of registration (DeepWrinkles Sec. 3.1) and capture."""
