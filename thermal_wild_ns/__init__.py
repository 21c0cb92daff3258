"""thermal_wild_ns: thermal-only Gaussian splatting for nerfstudio ("Thermal is Always Wild")."""

from thermal_wild_ns._upstream import check_versions, explain_config_load_error
from thermal_wild_ns.errors import EXPLAINERS, IncompleteConfig

check_versions()  # the patches in _upstream were checked against pinned nerfstudio/gsplat versions
# a damaged run config, as nerfstudio's loader meets it, explained in one line naming the file
EXPLAINERS.append(lambda error, traceback: explain_config_load_error(error, traceback, (IncompleteConfig,)))
