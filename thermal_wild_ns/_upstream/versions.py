"""The nerfstudio and gsplat versions every patch of `_upstream` was written against, checked at import."""

from __future__ import annotations

import os
from importlib import metadata

CHECKED = {"nerfstudio": "1.1.5", "gsplat": "1.4.0"}
"""The versions every patch here was written and tested against (pyproject.toml pins them)."""
SKIP_VERSION_CHECK = "THERMAL_WILD_NS_SKIP_VERSION_CHECK"
"""Set to 1 to try another nerfstudio/gsplat version at your own risk."""


def check_versions() -> None:
    """Fail with a clear message where nerfstudio or gsplat is not the version the patches below
    were checked against: they reach into internals that change between versions."""
    if os.environ.get(SKIP_VERSION_CHECK) == "1":
        return
    wrong = []
    for package, wanted in CHECKED.items():
        try:
            found = metadata.version(package)
        except metadata.PackageNotFoundError:
            found = "not installed"
        if found != wanted:
            wrong.append(f"{package} {found} (needs {wanted})")
    if wrong:
        raise ImportError(
            f"thermal_wild_ns needs {', '.join(f'{p}=={v}' for p, v in CHECKED.items())}; found {', '.join(wrong)}. "
            f"Install the pinned versions (pip install .), or set {SKIP_VERSION_CHECK}=1 to try anyway."
        )


check_versions()
