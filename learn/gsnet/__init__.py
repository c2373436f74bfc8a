"""GSNet (graph skinning network): its inputs (``features``), network (``network``) and garment
batches (``data``); the trainable method is ``learn.methods.gsnet``."""
