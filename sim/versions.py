"""Installed versions of the packages a result depends on, recorded beside every output
(stage metadata, quality reports, dataset manifests, checkpoints)."""

from __future__ import annotations

CORE_PACKAGES = ("wrinkles", "warp-lang", "numpy")
"""The packages every result of the toolkit depends on."""


def package_versions(*extra: str) -> dict[str, str]:
    """``{distribution name: version}`` of ``CORE_PACKAGES`` and ``extra`` ones (e.g.
    ``"usd-core"``, ``"torch"``); a package that is not installed is left out."""
    import importlib.metadata as md

    out = {}
    for pkg in (*CORE_PACKAGES, *extra):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out
