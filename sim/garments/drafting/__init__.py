"""Sewing patterns drafted from body measurements, with their panels placed around the body."""
