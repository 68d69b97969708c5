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
import os
from dataclasses import dataclass, field
from pathlib import Path

from monitors.errors import UserError
from monitors.ir.functions import expand_functions
from supervisor.config.analysis import load_analysis
from supervisor.config.control import load_control
from supervisor.config.fields import check_keys, error_at
from supervisor.config.functions import load_functions
from supervisor.config.imported import Imports, decode, read_bytes
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


@dataclass(frozen=True)
class ConfigSource:
    """The config file's bytes as read once, with their SHA-256: what a start or a
    reload loads, validates and compiles, and what the analyses' child process is
    given, so that nothing downstream reads the file again and sees another edit
    (docs/ARCHITECTURE.md, "The stages")."""

    path: str  # for error positions and the files it imports, relative to it
    data: bytes
    sha256: str
    # The files it imports, read at its first load and kept (given to the child).
    imports: Imports = field(default_factory=Imports, compare=False)

    @classmethod
    def of(
        cls, path: str | Path, data: bytes, imports: dict[str, bytes] | None = None
    ) -> ConfigSource:
        return cls(str(Path(path)), data, hashlib.sha256(data).hexdigest(), Imports(imports))

    def identity(self) -> str:
        """What the config judges with, as one SHA-256: ``sha256`` when it imports
        nothing, else a hash of it and of each imported file's name (relative to the
        config) and bytes.  A changed FRET export under an unchanged config is then
        another config to whoever keys results by it (fleet replay's dataset,
        docs/reference/fleet.md).  Known once the config is loaded: its imports are
        read then."""
        digests = self.import_digests()
        if not digests:
            return self.sha256
        h = hashlib.sha256(f"config {self.sha256}\0".encode())
        for name, digest in digests.items():
            h.update(f"import {name}\0{digest}\0".encode())
        return h.hexdigest()

    def import_digests(self) -> dict[str, str]:
        """Each imported file's SHA-256 by its name relative to the config, sorted:
        what the violation log's start record keeps, so that ``report`` can tell an
        edited import under an unchanged config (docs/reference/log.md)."""
        base = Path(self.path).parent
        return dict(
            sorted(
                (os.path.relpath(k, base), hashlib.sha256(v).hexdigest())
                for k, v in self.imports.files().items()
            )
        )


def read_config(path: str | Path) -> ConfigSource:
    """The file at ``path``, read once: capped before parsing, a regular file only
    (docs/reference/config.md, "Limits")."""
    return ConfigSource.of(path, read_bytes(path, "config", MAX_CONFIG_BYTES))


def load_config(source: str | Path | ConfigSource) -> Config:
    """The Config of a file (read here) or of a :class:`ConfigSource` already read."""
    if not isinstance(source, ConfigSource):
        source = read_config(source)
    path = Path(source.path)
    file = source.path
    # UTF-8 with the bad byte located.
    doc = load_yaml(path, decode(source.data, file))
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
    variables = load_variables(doc, path, source.imports)
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
    requirements = load_requirements(doc, path, notes, source.imports)
    mitigations = load_mitigations(doc)
    log_path, recent, log_retry_buffer = load_violation_log(doc)
    log_durability = load_durability(doc)
    on_stale = load_on_stale(doc, mitigations)
    check_on_violation(requirements, mitigations)
    for r in requirements:
        r.policy_config = policy_config(r, mitigations, variables, file)
    check_trigger(step, variables, doc)
    ros = load_ros(doc)
    control = load_control(doc, path)
    limits = load_limits(doc)
    record = load_record(doc)
    # Last: its errors came after every other section's when the analyses judged it.
    analysis = load_analysis(doc, file)
    return Config(
        path=file,
        sha256=source.sha256,
        identity=source.identity(),  # every import read by now
        import_digests=source.import_digests(),
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
        analysis=analysis,
        ros=ros,
        control=control,
        limits=limits,
        record=record,
        notes=notes,
    )
