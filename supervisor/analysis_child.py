"""The analyses of ``run`` and reload in a child process, and that child.

z3 keeps memory after it is done with it (1.2 GB after the analyses of 10
generated requirements, malloc_trim included; docs/BENCHMARKS.md, "Scaling"),
which the daemon must not carry for the rest of its run; and the monitor can be
compiled while the child works.  The child is given the config's bytes as the
daemon read them, not the file's path: it judges the config the monitor is
compiled from even when the file is edited meanwhile, and answers with the
SHA-256 of what it judged, which the daemon compares with its own
(docs/ARCHITECTURE.md, "The stages").

The child: ``python -m supervisor.analysis_child FILE SHA256 [--k K]`` with the
config's bytes and those of the files it imports, as the daemon read them, on
stdin (one JSON document; FILE names them in errors); its answer is one JSON line on stdout, ``{"sha256": ..., "findings":
[...]}`` (no traces).
"""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import tempfile

from monitors.verify.analysis import Finding
from supervisor.cache import Cache
from supervisor.config import ConfigSource
from supervisor.pipeline import Project, project_for
from supervisor.validation import (
    Validation,
    cached_findings,
    finding_json,
    finding_of,
    open_cache,
    partial,
    project_requirements,
    startup_key,
    validate,
    validate_project,
)

CHILD_GRACE_S = 60.0  # beyond the analyses' budget: start-up, the project, exit
# Unrollings up to this many solver terms are analysed in the daemon itself: a
# fraction of a second and a few MB (sRobot: 222, mobile-base: 672), where a child
# would add its start (about 1.5 s) to every start and reload.
IN_PROCESS_CELLS = 20_000


def _unrolling_cells(project: Project, k: int | None) -> int:
    from monitors.verify.analysis.requirements import default_k
    from monitors.verify.bmc import encoding_cells

    reqs, _ = project_requirements(project)
    k = k or project.config.analysis.k or default_k(reqs)
    return encoding_cells([f for r in reqs for f in (r.formula, r.activation)], k)


class Aside:
    """:func:`~supervisor.validation.validate` for the daemon (``run``, reload): the
    project is judged here, the analyses of a large set in a child process, of which
    only the findings come back (:meth:`result` waits for them)."""

    def __init__(self, source: ConfigSource, k: int | None = None) -> None:
        from supervisor.children import child_env, start

        cache = open_cache()
        self.source = source
        self.project = project_for(source)
        self._proc: subprocess.Popen[bytes] | None = None
        self._done: Validation | None = None
        self.cache: Cache | None = None
        self.key: str | None = None
        if not self.project.ok:
            self._done = Validation(self.project, None, "the config has errors")
            return
        self.cache, self.key = startup_key(self.project, k, cache)
        if not self.project.config.analysis.enabled:
            self._done = Validation(self.project, None, "analysis.enabled is false")
        elif (hit := cached_findings(self.project, self.cache, self.key)) is not None:
            self._done = hit
        elif _unrolling_cells(self.project, k) <= IN_PROCESS_CELLS:
            # Small: not worth a process start.
            self._done = validate_project(self.project, k, self.cache, self.key)
            if self._done.analysis is not None:
                self._done.analysis.find_examples = None  # nothing asks the solver again
        else:
            argv = [sys.executable, "-m", __name__, source.path, source.sha256]
            argv += [] if k is None else ["--k", str(k)]
            # The bytes in an unnamed file: the child reads them when it is ready,
            # while this thread compiles the monitor (a pipe would block on a large
            # config until the child reads). The files it imports go with it, as
            # read here: the child judges this version of them, not the disk's.
            with tempfile.TemporaryFile() as stdin:
                stdin.write(_payload(source))
                stdin.seek(0)
                self._proc = start(
                    argv,
                    env=child_env(),
                    stdin=stdin,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE,
                )

    def result(self) -> Validation:
        if self._done is not None:
            return self._done
        assert self._proc is not None
        project, proc = self.project, self._proc
        wait_s = project.config.limits.analysis_budget_s + CHILD_GRACE_S
        try:
            out, err = proc.communicate(timeout=wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            self._done = Validation(project, None, f"the analyses did not end within {wait_s:g} s")
            return self._done
        try:
            answer = json.loads(out.decode().strip().splitlines()[-1])
            sha256 = str(answer["sha256"])
            findings = [finding_of(f) for f in answer["findings"]]
        except (ValueError, IndexError, KeyError, TypeError):
            last = (err.decode(errors="replace").strip().splitlines() or ["no output"])[-1]
            why = f"the analyses' process failed (exit {proc.returncode}): {last}"
            self._done = Validation(project, None, why)
            return self._done
        if sha256 != self.source.sha256:
            # Findings of another config are no findings of this one.
            why = f"the analyses' process judged another config (sha256 {sha256})"
            self._done = Validation(project, None, why)
            return self._done
        errors = [f for f in findings if f.severity == "error"]
        self._done = Validation(project, None, partial(findings), child_errors=errors)
        return self._done

    def cancel(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.communicate()


def _payload(source: ConfigSource) -> bytes:
    """What the child reads on stdin: the config's bytes and its imports'."""
    b64 = base64.b64encode
    files = {p: b64(d).decode() for p, d in source.imports.files().items()}
    return json.dumps({"config": b64(source.data).decode(), "imports": files}).encode()


def _source(path: str, payload: bytes) -> ConfigSource:
    """The parent's :func:`_payload` back as a :class:`ConfigSource`."""
    doc = json.loads(payload)
    imports = {p: base64.b64decode(d) for p, d in doc["imports"].items()}
    return ConfigSource.of(path, base64.b64decode(doc["config"]), imports)


def main(argv: list[str]) -> int:
    """The child (module docstring): the analyses of the config on stdin."""
    import argparse

    p = argparse.ArgumentParser(prog=f"python -m {__name__}")
    p.add_argument("file")
    p.add_argument("sha256")
    p.add_argument("--k", type=int, default=None)
    args = p.parse_args(argv)
    source = _source(args.file, sys.stdin.buffer.read())
    if source.sha256 != args.sha256:
        print(f"the config on stdin is not sha256 {args.sha256}", file=sys.stderr)
        return 1
    checked = validate(source, args.k)
    found: list[Finding] = checked.analysis.findings if checked.analysis is not None else []
    answer = {"sha256": source.sha256, "findings": [finding_json(f) for f in found]}
    print(json.dumps(answer), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
