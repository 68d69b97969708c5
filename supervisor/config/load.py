"""The configuration file: read it and validate it section by section.

Produces a Config of plain dataclasses (supervisor.config.model).  Everything a
safety engineer can get wrong is reported as ``FILE:LINE: what is wrong``:
unknown keys (with a suggestion), missing topics, undefined mitigations,
duplicate ids, reserved or unusable variable names.  Each section has its own
module; this one runs them in order and checks what spans sections (names of
mitigations and variables used elsewhere).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from monitors.errors import UserError
from monitors.ir.functions import expand_functions
from supervisor.config.control import load_control
from supervisor.config.fields import as_mapping, check_keys, error_at
from supervisor.config.functions import load_functions
from supervisor.config.imported import decode, read_bytes
from supervisor.config.limits import MAX_CONFIG_BYTES, load_limits
from supervisor.config.mitigations import load_mitigations, load_on_stale
from supervisor.config.model import Config
from supervisor.config.record import load_record
from supervisor.config.requirements import check_on_violation, load_requirements, policy_config
from supervisor.config.ros import load_ros
from supervisor.config.step import check_trigger, load_step
from supervisor.config.variables import load_variables
from supervisor.config.violation_log import load_durability, load_violation_log
from supervisor.config.yamlload import load_yaml

TOP_KEYS = {
    "component",
    "step",
    "variables",
    "variables_from",
    "functions",
    "requirements",
    "requirements_from",
    "requirement_defaults",
    "mitigations",
    "logging",
    "on_stale",
    "analysis",
    "ros",
    "control",
    "limits",
    "record",
}


def load_config(path: str | Path) -> Config:
    path = Path(path)
    file = str(path)
    # Capped before parsing, a regular file only, UTF-8 with the bad byte located
    # (docs/reference/config.md, "Limits").
    raw_bytes = read_bytes(path, "config", MAX_CONFIG_BYTES)
    doc = load_yaml(path, decode(raw_bytes, file))
    if not isinstance(doc, dict):
        raise UserError(
            "the config must be a YAML mapping (component:, variables:, requirements:, ...)",
            file=file,
            line=1,
        )
    check_keys(doc, TOP_KEYS, "the config")

    component = doc.get("component")
    if not isinstance(component, str) or not component:
        raise error_at(
            "'component' is required: the FRETISH component the requirements name",
            doc,
            "component",
            file=file,
        )

    # The order of the sections is the order their errors are found in.
    step = load_step(doc)
    variables = load_variables(doc, path)
    functions = load_functions(doc)
    for v in variables.values():  # a define may call the config's functions
        if v.define is not None:
            try:
                v.define = expand_functions(v.define, functions)
            except UserError as e:
                raise UserError(
                    f"define of '{v.name}' {e.message}", file=file, line=v.line, hint=e.hint
                ) from None
    notes: list[str] = []
    requirements = load_requirements(doc, path, notes)
    mitigations = load_mitigations(doc)
    log_path, recent, log_retry_buffer = load_violation_log(doc)
    log_durability = load_durability(doc)
    on_stale = load_on_stale(doc, mitigations)
    check_on_violation(requirements, mitigations)
    for r in requirements:
        r.policy_config = policy_config(r, mitigations, variables, file)
    check_trigger(step, variables, doc)
    analysis = as_mapping(doc.get("analysis") or {}, doc, "analysis", "analysis")
    ros = load_ros(doc)
    control = load_control(doc, path)
    limits = load_limits(doc)
    record = load_record(doc)
    return Config(
        path=file,
        sha256=hashlib.sha256(raw_bytes).hexdigest(),
        component=str(component),
        step=step,
        variables=variables,
        functions=functions,
        requirements=requirements,
        mitigations=mitigations,
        log_path=log_path,
        recent=recent,
        log_retry_buffer=log_retry_buffer,
        log_durability=log_durability,
        on_stale=on_stale,
        analysis=dict(analysis),
        ros=ros,
        control=control,
        limits=limits,
        record=record,
        notes=notes,
    )
