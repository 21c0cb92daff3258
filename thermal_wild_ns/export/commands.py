"""`wild-thermal-export`: a trained run out as files a user opens elsewhere.

- `gaussian-splat`: ns-export's splat PLY, plus each Gaussian's thermal value and the state it was
  baked at (`gaussian_splat.py`);
- `celsius-points`: the opaque Gaussians with their °C, where the site is (`survey.py`);
- `orthomosaic`: a °C GeoTIFF rendered straight down at the canonical state (`survey.py`).
"""

from __future__ import annotations

import tyro

from thermal_wild_ns.errors import report_input_errors_briefly
from thermal_wild_ns.export.gaussian_splat import ExportThermalSplat
from thermal_wild_ns.export.survey import ExportCelsiusPoints, ExportOrthomosaic


def entrypoint():
    report_input_errors_briefly()
    # a subcommand per format, as ns-export reads: wild-thermal-export gaussian-splat --load-config ...
    tyro.extras.subcommand_cli_from_dict(
        {
            "gaussian-splat": tyro.conf.FlagConversionOff[ExportThermalSplat],
            "celsius-points": tyro.conf.FlagConversionOff[ExportCelsiusPoints],
            "orthomosaic": tyro.conf.FlagConversionOff[ExportOrthomosaic],
        },
        description=__doc__.splitlines()[0],
    ).main()


if __name__ == "__main__":
    entrypoint()
