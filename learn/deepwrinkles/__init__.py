"""DeepWrinkles (Lähner, Cremers, Tung, ECCV 2018): a pose-normalised linear subspace of
registered garment shapes (``subspace``), pose-to-shape regression, and a conditional GAN that
adds fine wrinkles as tangent-space normal maps."""
