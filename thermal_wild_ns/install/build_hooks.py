"""setuptools hook (see [tool.setuptools.cmdclass] in pyproject.toml): ships the torchvision CPU
shim (`thermal_wild_ns_torchvision_cpu.py`) and the `.pth` file that imports it at interpreter
start into the root of site-packages. They live outside the package so that starting Python
never imports (and pins) `thermal_wild_ns` itself."""

from pathlib import Path

from setuptools.command.build_py import build_py

_HERE = Path(__file__).parent
ROOT_FILES = ("thermal_wild_ns_torchvision_cpu.pth", "thermal_wild_ns_torchvision_cpu.py")


class BuildPyWithStartupShim(build_py):
    def run(self):
        super().run()
        for name in ROOT_FILES:
            self.copy_file(str(_HERE / name), str(Path(self.build_lib) / name), preserve_mode=0)

    def get_outputs(self, include_bytecode=True):
        return super().get_outputs(include_bytecode) + [str(Path(self.build_lib) / n) for n in ROOT_FILES]
