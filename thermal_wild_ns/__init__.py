"""thermal_wild_ns: thermal-only Gaussian splatting for nerfstudio ("Thermal is Always Wild").

Importing the package imports nothing heavy: each module imports what it uses (`_upstream`
checks the nerfstudio and gsplat versions its patches were written for when it is first imported).
"""

import importlib
import importlib.abc
import importlib.util
import sys

MOVED_MODULES = {
    "thermal_wild_ns.data.datamanager": "thermal_wild_ns.pipeline.datamanager",
    "thermal_wild_ns.training.guard": "thermal_wild_ns.training.trainer",
}
"""Modules that moved, old name -> new: a run's config.yml names its classes by module path, and
runs trained before a move must still load in ns-viewer, ns-render and ns-eval."""


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Import an old module name as the module it moved to (the same module object)."""

    def find_spec(self, fullname, path, target=None):
        if fullname not in MOVED_MODULES:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        return importlib.import_module(MOVED_MODULES[spec.name])

    def exec_module(self, module) -> None:
        pass  # already executed under its new name


if not any(isinstance(finder, _MovedModuleFinder) for finder in sys.meta_path):
    sys.meta_path.append(_MovedModuleFinder())
