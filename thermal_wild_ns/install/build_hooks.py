"""setuptools hook (see [tool.setuptools.cmdclass] in pyproject.toml): ships
`thermal_wild_ns_torchvision_cpu.pth` into the root of site-packages. At interpreter start it
loads `thermal_wild_ns/install/torchvision_shim.py` on its own (not the package) and installs the
torchvision CPU shim (`install_torchvision_cpu_shim`), which must act before anything imports torchvision."""

from pathlib import Path

from setuptools.command.build_py import build_py

_HERE = Path(__file__).parent
ROOT_FILES = ("thermal_wild_ns_torchvision_cpu.pth",)


class BuildPyWithStartupShim(build_py):
    def run(self):
        super().run()
        for name in ROOT_FILES:
            self.copy_file(str(_HERE / name), str(Path(self.build_lib) / name), preserve_mode=0)

    def get_outputs(self, include_bytecode=True):
        return super().get_outputs(include_bytecode) + [str(Path(self.build_lib) / n) for n in ROOT_FILES]
