"""The configuration file: ``load_config(path) -> Config``.

One module per section (step, variables, requirements, mitigations, ros,
logging) plus the FRET and OGMA imports; ``load`` runs them in order.  The
mitigation and policy settings a Config carries are :mod:`mitigations.settings`'.
"""

from supervisor.config.fret import load_fret_export
from supervisor.config.load import ConfigSource, load_config, read_config
from supervisor.config.model import Config, RequirementEntry, RosConfig, StepConfig, Variable
from supervisor.config.ogma import load_ogma_variables

__all__ = [
    "Config",
    "ConfigSource",
    "RequirementEntry",
    "RosConfig",
    "StepConfig",
    "Variable",
    "load_config",
    "load_fret_export",
    "load_ogma_variables",
    "read_config",
]
