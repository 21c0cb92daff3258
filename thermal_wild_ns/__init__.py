"""thermal_wild_ns: thermal-only Gaussian splatting for nerfstudio ("Thermal is Always Wild")."""

from thermal_wild_ns._upstream import check_versions

check_versions()  # the patches in _upstream were checked against pinned nerfstudio/gsplat versions
